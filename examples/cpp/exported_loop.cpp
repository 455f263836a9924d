// A control loop driven by a policy's two exported programs from C++ with libtorch alone (no
// Python): the tracker every 1 ms tick, the planner every --plan-every ticks (the decision
// interval by default), each program's state passed in and taken back at every call. The C++
// twin of examples/exported_loop.py's run_loop.
//
//   python -c "import protorch; protorch.load('runs/arm', planner='thread').export('arm_programs', aoti=True)"
//   python examples/cpp/raw.py inputs inputs.pt raw_in   # or write the raw files yourself
//   build/cpp/exported_loop arm_programs raw_in --out raw_out
//   python examples/cpp/raw.py outputs raw_out out.pt    # the same keys as exported_loop.py's --out
//
// Both programs must be AOTInductor packages (export(folder, aoti=True)): libtorch cannot run a
// torch.export program that is not compiled. The packages' shared libraries are built for the
// torch version that compiled them: link this program against the same libtorch.
//
// Inputs (folder INPUTS): raw little-endian float64, row-major, no header:
//   env.f64 (T, env_dim) one environment per tick; q0.f64, qd0.f64 (D,) the arm at the start.
// Outputs (folder --out): q.f64, qd.f64, qdd.f64 (T, D); label.i64 (T,) int64; plan_t.f64 (T,);
//   tracker_s.f64, tracker_cpu_s.f64 (T,) the tracker's wall (steady_clock) and thread CPU
//   seconds per call; planner_s.f64 (one per plan) the planner's wall seconds per call.
// From programs.json it reads dof, num_basis, env_dim, decision_dt, tick and the aoti flags.
//
// The arm is taken to follow the reference exactly (the measured q, qd handed to both programs
// are the last tick's reference); a robot's loop hands over what it measures, and with the run's
// jerk limits (programs.json's "limits") applies Ruckig to the tracker's output. This does not.
#include <ATen/Parallel.h>
#include <ATen/core/Tensor.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/scalar_tensor.h>
#include <ATen/ops/zeros.h>
#include <torch/csrc/inductor/aoti_package/model_package_loader.h>
#include <torch/headeronly/version.h>

#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

using Tensors = std::vector<at::Tensor>;

std::string read_text(const std::string& path) {
  std::ifstream f(path);
  if (!f) throw std::runtime_error("cannot read " + path);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

// The text after programs.json's "key": (json.dumps's output: one key per name used here).
std::string json_value(const std::string& text, const std::string& key) {
  auto at = text.find("\"" + key + "\":");
  if (at == std::string::npos) throw std::runtime_error("programs.json has no \"" + key + "\"");
  auto start = text.find_first_not_of(" \n", at + key.size() + 3);
  return text.substr(start, text.find_first_of(",\n}", start) - start);
}

double json_number(const std::string& text, const std::string& key) {
  return std::stod(json_value(text, key));
}

template <typename T>
std::vector<T> read_raw(const std::string& path, size_t multiple_of) {
  std::ifstream f(path, std::ios::binary | std::ios::ate);
  if (!f) throw std::runtime_error("cannot read " + path);
  auto bytes = static_cast<size_t>(f.tellg());
  if (bytes == 0 || bytes % (sizeof(T) * multiple_of) != 0) {
    throw std::runtime_error(
        path + ": " + std::to_string(bytes) + " bytes, not a whole number of rows of " +
        std::to_string(multiple_of) + " values of " + std::to_string(sizeof(T)) + " bytes");
  }
  std::vector<T> out(bytes / sizeof(T));
  f.seekg(0);
  f.read(reinterpret_cast<char*>(out.data()), static_cast<std::streamsize>(bytes));
  return out;
}

template <typename T>
void write_raw(const std::string& path, const std::vector<T>& data) {
  // atomic: the whole file under a temporary name, then renamed over the target
  std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char*>(data.data()),
            static_cast<std::streamsize>(data.size() * sizeof(T)));
    if (!f) throw std::runtime_error("cannot write " + tmp);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) throw std::runtime_error("cannot write " + path);
}

// A 1-d float64 tensor holding a copy of data[offset : offset + n].
at::Tensor vector_f64(const std::vector<double>& data, size_t offset, int64_t n) {
  at::Tensor t = at::empty({n}, at::TensorOptions().dtype(at::kDouble));
  std::memcpy(t.data_ptr<double>(), data.data() + offset, n * sizeof(double));
  return t;
}

double thread_cpu_s() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

struct Result {
  std::vector<double> q, qd, qdd, plan_t, tracker_s, tracker_cpu_s, planner_s;
  std::vector<int64_t> label;
};

// T = envs.size() / env_dim ticks of `tick` seconds: the planner at every plan_every-th tick (before
// that tick's tracker call, on that tick's inputs), the tracker at every tick (run_loop of
// examples/exported_loop.py).
Result run_loop(torch::inductor::AOTIModelPackageLoader& planner,
                torch::inductor::AOTIModelPackageLoader& tracker, int64_t d, int64_t kb,
                int64_t env_dim, double tick, const std::vector<double>& envs,
                const std::vector<double>& q0, const std::vector<double>& qd0, int64_t plan_every) {
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  const auto i64 = at::TensorOptions().dtype(at::kLong);
  const int64_t ticks = static_cast<int64_t>(envs.size()) / env_dim;
  // the planner's state: the class row (-1: none yet) and the decision slot
  at::Tensor current = at::scalar_tensor(-1, i64), slot = at::scalar_tensor(-1, i64);
  // the tracker's state: the last plan's weights, the last time, the offset, started
  Tensors state = {at::zeros({kb, d}, f64), at::zeros({}, f64), at::zeros({2, d}, f64),
                   at::zeros({}, f64)};
  at::Tensor q = vector_f64(q0, 0, d), qd = vector_f64(qd0, 0, d);
  at::Tensor W, label, plan_t;
  Result r;
  for (auto* v : {&r.q, &r.qd, &r.qdd}) v->reserve(ticks * d);
  for (auto* v : {&r.plan_t, &r.tracker_s, &r.tracker_cpu_s}) v->reserve(ticks);
  r.label.reserve(ticks);
  for (int64_t i = 0; i < ticks; ++i) {
    at::Tensor t = at::scalar_tensor(static_cast<double>(i) * tick, f64);
    if (i % plan_every == 0) {
      at::Tensor env = vector_f64(envs, i * env_dim, env_dim);
      const auto p0 = std::chrono::steady_clock::now();
      Tensors out = planner.run({env, t, q, qd, current, slot});
      r.planner_s.push_back(
          std::chrono::duration<double>(std::chrono::steady_clock::now() - p0).count());
      W = out[0], label = out[1], current = out[2], slot = out[3], plan_t = out[4];
    }
    const double c0 = thread_cpu_s();
    const auto t0 = std::chrono::steady_clock::now();
    Tensors out = tracker.run({t, W, q, qd, state[0], state[1], state[2], state[3]});
    const auto t1 = std::chrono::steady_clock::now();
    r.tracker_cpu_s.push_back(thread_cpu_s() - c0);
    r.tracker_s.push_back(std::chrono::duration<double>(t1 - t0).count());
    state = {out[3], out[4], out[5], out[6]};
    q = out[0], qd = out[1];  // the arm on its reference
    const double* p = q.data_ptr<double>();
    r.q.insert(r.q.end(), p, p + d);
    p = qd.data_ptr<double>();
    r.qd.insert(r.qd.end(), p, p + d);
    p = out[2].data_ptr<double>();
    r.qdd.insert(r.qdd.end(), p, p + d);
    r.label.push_back(*label.data_ptr<int64_t>());
    r.plan_t.push_back(*plan_t.data_ptr<double>());
  }
  return r;
}

// median, p99 and max of seconds, in ms (the indices of examples/exported_loop.py)
std::string summary(std::vector<double> s) {
  std::sort(s.begin(), s.end());
  const size_t n = s.size(), p99 = std::min(n - 1, static_cast<size_t>(0.99 * n));
  char buf[128];
  std::snprintf(buf, sizeof buf, "median %.4f ms, p99 %.4f ms, max %.4f ms", 1e3 * s[n / 2],
                1e3 * s[p99], 1e3 * s[n - 1]);
  return buf;
}

[[noreturn]] void usage(const char* why) {
  std::cerr << "usage: exported_loop FOLDER INPUTS [--out DIR] [--plan-every N] [--threads N]\n"
            << "  FOLDER: written by policy.export(folder, aoti=True); INPUTS: a folder of raw\n"
            << "  float64 env.f64 (T, env_dim), q0.f64 and qd0.f64 (D,)\n"
            << why << "\n";
  std::exit(2);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) usage("give FOLDER and INPUTS");
  const std::string folder = argv[1], inputs = argv[2];
  std::string out_dir;
  int64_t plan_every = 0, threads = 1;
  for (int a = 3; a < argc; a += 2) {
    const std::string flag = argv[a];
    if (a + 1 >= argc) usage(("no value after " + flag).c_str());
    if (flag == "--out") {
      out_dir = argv[a + 1];
    } else if (flag == "--plan-every") {
      plan_every = std::stoll(argv[a + 1]);
    } else if (flag == "--threads") {
      threads = std::stoll(argv[a + 1]);
    } else {
      usage(("unknown option " + flag).c_str());
    }
  }
  try {
    const std::string meta = read_text(folder + "/programs.json");
    for (const char* name : {"planner", "tracker"}) {
      if (json_value(meta, name) != "true") {
        throw std::runtime_error(std::string(name) + ".pt2 of " + folder +
                                 " is not an AOTInductor package: export(folder, aoti=True)");
      }
    }
    const auto d = static_cast<int64_t>(json_number(meta, "dof"));
    const auto kb = static_cast<int64_t>(json_number(meta, "num_basis"));
    const auto env_dim = static_cast<int64_t>(json_number(meta, "env_dim"));
    const double tick = json_number(meta, "tick");
    if (plan_every <= 0) {
      plan_every = std::max<int64_t>(1, std::llround(json_number(meta, "decision_dt") / tick));
    }
    const auto envs = read_raw<double>(inputs + "/env.f64", env_dim);
    const auto q0 = read_raw<double>(inputs + "/q0.f64", d);
    const auto qd0 = read_raw<double>(inputs + "/qd0.f64", d);
    if (q0.size() != static_cast<size_t>(d) || qd0.size() != static_cast<size_t>(d)) {
      throw std::runtime_error("q0.f64 and qd0.f64 must hold dof = " + std::to_string(d) +
                               " values each");
    }
    at::set_num_threads(static_cast<int>(threads));  // a pool's workers only compete for cores
    torch::inductor::AOTIModelPackageLoader planner(folder + "/planner.pt2");
    torch::inductor::AOTIModelPackageLoader tracker(folder + "/tracker.pt2");
    Result r = run_loop(planner, tracker, d, kb, env_dim, tick, envs, q0, qd0, plan_every);
    const std::set<int64_t> classes(r.label.begin(), r.label.end());
    std::cout << r.tracker_s.size() << " ticks, a plan every " << plan_every
              << ": tracker wall " << summary(r.tracker_s) << "; CPU " << summary(r.tracker_cpu_s)
              << "; planner (" << r.planner_s.size() << " calls) wall " << summary(r.planner_s)
              << "; classes [";
    for (auto it = classes.begin(); it != classes.end(); ++it) {
      std::cout << (it == classes.begin() ? "" : ", ") << *it;
    }
    std::cout << "]; C++, libtorch " << TORCH_VERSION_MAJOR << "." << TORCH_VERSION_MINOR << "."
              << TORCH_VERSION_PATCH << std::endl;
    if (!out_dir.empty()) {
      std::filesystem::create_directories(out_dir);
      write_raw(out_dir + "/q.f64", r.q);
      write_raw(out_dir + "/qd.f64", r.qd);
      write_raw(out_dir + "/qdd.f64", r.qdd);
      write_raw(out_dir + "/label.i64", r.label);
      write_raw(out_dir + "/plan_t.f64", r.plan_t);
      write_raw(out_dir + "/tracker_s.f64", r.tracker_s);
      write_raw(out_dir + "/tracker_cpu_s.f64", r.tracker_cpu_s);
      write_raw(out_dir + "/planner_s.f64", r.planner_s);
    }
  } catch (const std::exception& e) {
    std::cerr << "exported_loop: " << e.what() << std::endl;
    return 1;
  }
  return 0;
}
