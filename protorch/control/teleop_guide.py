"""A virtual guide for teleoperation in a changing scene: a mixture of ProMPs re-inferred from the
environment map as the wall moves (the follow-up of Ewerton, Arenz, Peters 2020, on PRO's map).

At every control step, for ``B`` trials at once (:meth:`MixtureGuide.step`):

1. **Re-inference.** The map gives, for the wall's current pose ``e`` and each class ``k``, the
   mean weights (Eq. 7) and the solutions' variance (the log-variance regressed by a second map of
   the same kind, :func:`variance_map`: the spread the optimiser kept, not the GP's own
   uncertainty), hence a mean ``mu_k(z)`` and a marginal std ``sigma_k(z)`` on the phase grid.
   A *fixed* guide uses the wall's first pose throughout.
2. **Progress** from the beam's pose: per class, the first phase ``z_k`` at which the mean has
   advanced as far along ``axis`` (start to end) as the beam has, never before the last one (the
   operator sets the pace, not the clock). The pull toward ``mu_k(z_k)`` then has no part along
   the axis: the guide corrects the path, it does not brake or drag the motion.
3. **Belief** over the classes: ``b_k <- b_k exp(-0.5 dt / tau * d_k^2)`` renormalised, with
   ``d_k`` the distance of the operator's commanded pose (the device's pose plus the measured
   interaction force over the hand's stiffness; in simulation the wish) to ``mu_k(z_k)``, per
   coordinate over its std plus ``obs_std``, and a floor ``belief_floor``. Both classes start
   equally likely, so the guide follows the way the operator rolls the beam; evidence from the
   device's own pose would let the guide's pull confirm itself.
4. **The pull**: ``F = sum_k b_k K_k (mu_k(z_k) - x)`` with ``K_k = clip(gain / sigma_k, k_min,
k_max)``
   per coordinate (:func:`~protorch.control.guidance.stiffness_law`): firm where the distribution
   is narrow, free where it is wide. A class the operator moves away from loses its weight, so
   the guide does not pull them across to it.
5. **The hand** holds the device with stiffness ``K_h`` around the operator's wish ``w``; the device
   settles where the springs balance (quasi-static, as :meth:`HapticGuidance.assist`):
   ``x = (K_h w + sum_k b_k K_k mu_k) / (K_h + sum_k b_k K_k)`` per coordinate, quaternion
   renormalised. The progress is found on ``w`` and found again on that balance.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .guidance import STIFFNESS_DEFAULTS, stiffness_law

__all__ = ["MixtureGuide", "GuideState", "variance_map", "GUIDE_DEFAULTS"]

GUIDE_DEFAULTS = dict(
    **STIFFNESS_DEFAULTS,
    hand_position=300.0,
    hand_rotation=3.0,
    tau=0.3,
    obs_std=0.05,
    belief_floor=1e-3,
)


def variance_map(env_map_factory, env_map) -> object:
    """A map of the same kind fitted to ``log VAR`` of ``env_map``'s entries (the regressed
    log-variance of the solutions, per weight and label)."""
    vm = env_map_factory()
    logv = env_map.VAR.clamp_min(1e-12).log()  # (M, N)
    vm.fit(env_map.E, logv, torch.full_like(logv, 1e-2), env_map.labels)
    return vm


@dataclass
class GuideState:
    """Per trial: phase per class ``z (B, K)`` in grid steps (fractional) and belief ``(B, K)``."""

    z: Tensor
    belief: Tensor


class MixtureGuide:
    """The guide of the module docstring.

    Args:
        promp: the :class:`~protorch.ProMP` (``D = 7``: position and quaternion components) of the
        map.
        env_map, var_map: the map of mean weights and that of their log-variance
        (:func:`variance_map`).
        labels: the classes to mix (each must be in the map).
        settings: :data:`GUIDE_DEFAULTS` keys (gains in N and N/m, the hand's stiffnesses, the
            progress search, the belief's time constant ``tau`` in s).
    """

    def __init__(self, promp, env_map, var_map, labels, axis, **settings) -> None:
        unknown = sorted(set(settings) - set(GUIDE_DEFAULTS))
        if unknown:
            raise ValueError(
                f"unknown guide setting(s) {unknown}; allowed: {sorted(GUIDE_DEFAULTS)}"
            )
        self.cfg = {**GUIDE_DEFAULTS, **settings}
        self.promp, self.env_map, self.var_map = promp, env_map, var_map
        self.labels = [int(k) for k in labels]
        axis = torch.as_tensor(axis, dtype=promp.basis.dtype).to(promp.basis.device)
        self.axis = axis / axis.norm()  # (3,) the direction of progress (start to end)
        self._last = None  # (env, infer(env)): the last inference
        dt = promp.basis.dtype
        c = self.cfg
        dev = promp.basis.device
        per = lambda a, b: torch.tensor([a] * 3 + [b] * 4, dtype=dt, device=dev)  # noqa: E731
        self.gain, self.k_max = (
            per(c["position_gain"], c["rotation_gain"]),
            per(c["position_max"], c["rotation_max"]),
        )
        self.k_min, self.k_hand = (
            per(c["position_min"], c["rotation_min"]),
            per(c["hand_position"], c["hand_rotation"]),
        )

    @property
    def num_classes(self) -> int:
        return len(self.labels)

    def start(self, batch: int) -> GuideState:
        """Every trial at phase 0 with equal belief."""
        dt = self.promp.basis.dtype
        k = self.num_classes
        kw = dict(dtype=dt, device=self.promp.basis.device)
        return GuideState(
            z=torch.zeros(batch, k, **kw), belief=torch.full((batch, k), 1.0 / k, **kw)
        )

    def infer(self, env: Tensor) -> tuple[Tensor, Tensor]:
        """``env (B, 4)`` -> mean ``(B, K, T, 7)`` (quaternion part unit) and std ``(B, K, T, 7)``;
        the last answer is kept and given again for the same walls (a wall stands still most of
        a trial)."""
        env = env.to(self.promp.basis)
        if (
            self._last is not None
            and self._last[0].shape == env.shape
            and torch.equal(self._last[0], env)
        ):
            return self._last[1]
        phi2 = self.promp.basis**2  # (T, nb)
        mus, stds = [], []
        for k in self.labels:
            mu_w = self.env_map.predict_mean(env, k)  # (B, N)
            var_w = self.var_map.predict_mean(env, k).exp()  # (B, N)
            mu = self.promp.trajectory(mu_w)  # (B, T, 7)
            var = torch.einsum("tk,bdk->btd", phi2, var_w.unflatten(-1, (7, -1)))  # (B, T, 7)
            q = mu[..., 3:] / mu[..., 3:].norm(dim=-1, keepdim=True).clamp_min(1e-9)
            mus.append(torch.cat([mu[..., :3], q], -1))
            stds.append(var.clamp_min(0).sqrt())
        out = torch.stack(mus, 1), torch.stack(stds, 1)
        self._last = (env.clone(), out)
        return out

    def _progress(self, mu: Tensor, pose: Tensor, z: Tensor) -> Tensor:
        """Phase ``(B, K)`` per class, in grid steps (fractional): where the mean has advanced as
        far along the start-to-end axis as ``pose (B, 7)`` has (linear between grid points;
        never before ``z``, the last one)."""
        axis = self.axis.to(mu)
        t = mu.shape[2]
        s_mu = (
            ((mu[..., :3] - mu[:, :, :1, :3]) * axis).sum(-1).cummax(-1).values.contiguous()
        )  # (B, K, T)
        s_x = ((pose[:, None, :3] - mu[:, :, 0, :3]) * axis).sum(-1)  # (B, K)
        hi = torch.searchsorted(s_mu, s_x[..., None].contiguous())[..., 0].clamp(1, t - 1)  # (B, K)
        s0, s1 = (
            s_mu.gather(-1, (hi - 1)[..., None])[..., 0],
            s_mu.gather(-1, hi[..., None])[..., 0],
        )
        frac = ((s_x - s0) / (s1 - s0).clamp_min(1e-12)).clamp(0, 1)
        return torch.maximum(hi - 1 + frac, z)

    def _balance(self, mu_z: Tensor, k: Tensor, belief: Tensor, wish: Tensor) -> Tensor:
        """The device pose ``(B, 7)`` where the hand's spring and the mixture's pulls balance."""
        q_w = wish[:, None, 3:]
        q_m = mu_z[..., 3:]
        q_m = torch.where(
            (q_m * q_w).sum(-1, keepdim=True) < 0, -q_m, q_m
        )  # in the wish's hemisphere
        target = torch.cat([mu_z[..., :3], q_m], -1)  # (B, K, 7)
        bk = belief[..., None] * k  # (B, K, 7)
        x = (self.k_hand * wish + (bk * target).sum(1)) / (self.k_hand + bk.sum(1))
        return torch.cat(
            [x[:, :3], x[:, 3:] / x[:, 3:].norm(dim=-1, keepdim=True).clamp_min(1e-9)], -1
        )

    def step(
        self, state: GuideState, wish: Tensor, env: Tensor, dt: float
    ) -> tuple[Tensor, GuideState, Tensor]:
        """One control step: ``wish (B, 7)`` and the wall ``env (B, 4)`` the guide conditions on ->
        ``(device pose (B, 7), new state, position compliance (B,))``; the compliance
        ``K_h / (K_h + K)`` (mean over x, y, z; 1 = free, 0 = locked) is the freedom measure."""
        device = wish.device  # the answer goes back where the wish came from
        wish, env = wish.to(self.promp.basis), env.to(self.promp.basis)
        mu, std = self.infer(env)  # (B, K, T, 7)

        def at(
            z,
        ):  # the means and stds at phases z (B, K), linear between grid points: (B, K, 7) each
            lo = z.floor().long().clamp(max=mu.shape[2] - 2)
            f = (z - lo)[..., None]
            idx = lo[..., None, None].expand(*z.shape, 1, 7)
            pick = lambda a: (1 - f) * a.gather(2, idx)[:, :, 0] + f * a.gather(2, idx + 1)[:, :, 0]  # noqa: E731
            return pick(mu), pick(std)

        # belief: how well each class explains the operator's commanded pose at its own phase
        mu_z, sd_z = at(self._progress(mu, wish, state.z))
        q_m = torch.where(
            (mu_z[..., 3:] * wish[:, None, 3:]).sum(-1, keepdim=True) < 0,
            -mu_z[..., 3:],
            mu_z[..., 3:],
        )
        diff = torch.cat([mu_z[..., :3], q_m], -1) - wish[:, None]  # (B, K, 7)
        d2 = (diff / (sd_z + self.cfg["obs_std"])).pow(2).sum(-1)  # (B, K)
        logb = state.belief.log() - 0.5 * dt / self.cfg["tau"] * (d2 - d2.amin(-1, keepdim=True))
        b = torch.softmax(logb, -1).clamp_min(self.cfg["belief_floor"])
        b = b / b.sum(-1, keepdim=True)
        x = wish
        for _ in range(2):
            z = self._progress(mu, x, state.z)
            mu_z, sd_z = at(z)
            k = stiffness_law(sd_z, self.gain, self.k_max, self.k_min)  # (B, K, 7)
            x = self._balance(mu_z, k, b, wish)
        bk = (b[..., None] * k).sum(1)  # (B, 7)
        compliance = (self.k_hand / (self.k_hand + bk))[:, :3].mean(-1)  # (B,)
        return x.to(device), GuideState(z=z, belief=b), compliance.to(device)
