#!/usr/bin/env bash
# One-command set-up of the external benchmark's own virtual environment (never protorch's):
#   bash benchmarks/studies/external/setup.sh            # -> benchmarks/studies/external/.venv (git-ignored)
#   PROTORCH_EXTERNAL_VENV=/some/path bash benchmarks/studies/external/setup.sh
# fancy-gym 0.3.0 pins mujoco==2.3.3 and imports gymnasium 0.29's EnvCompatibility wrapper, so it
# cannot share an environment with protorch's physics extra (mujoco 4). protorch itself is
# installed editable without extras, plus pycma for its CMAES.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../../.." && pwd)"
venv="${PROTORCH_EXTERNAL_VENV:-$here/.venv}"
python="${PYTHON:-python3}"
"$python" -m venv "$venv"
"$venv/bin/pip" install --upgrade pip
"$venv/bin/pip" install torch==2.13.0
"$venv/bin/pip" install fancy-gym==0.3.0 "gymnasium[mujoco]==0.29.1" cma
"$venv/bin/pip" install -e "$root"  # no extras: the physics extra would pull mujoco 4
"$venv/bin/python" -c "import fancy_gym, mujoco, protorch, cma; print('fancy_gym', fancy_gym.__file__, 'mujoco', mujoco.__version__)"
echo "ready: $venv/bin/python benchmarks/studies/external/run.py --help"
