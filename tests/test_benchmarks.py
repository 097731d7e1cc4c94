"""The benchmark scripts: the throughput smoke run (tiny sizes), its correctness gate, and
the aggregator's bookkeeping. Timings themselves are not checked (the machine is shared)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks import all as bench_all
from benchmarks import gpu, throughput

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_throughput_quick_smoke():
    """--quick with tiny sizes: the gate passes, every section is there, rates are positive.

    About 30 s of CPU (five XLA compilations; 35-70 s here on a shared machine), hence slow.
    """
    cmd = [
        sys.executable,
        str(ROOT / "benchmarks" / "throughput.py"),
        "--quick",
        "--controllers",
        "pd",
        "--dtypes",
        "float64",
        "--batches",
        "1",
        "--target",
        "400",
        "--single-steps",
        "200",
        "--numpy-batches",
        "1",
        "--numba-batches",
        "1",
        "--matmul-n",
        "256",
        "--all-cores-batches",
        "2",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    for key in (
        "machine",
        "protocol",
        "correctness",
        "throughput",
        "ratios",
        "step_cost",
        "peak",
        "flop_rates",
        "summary",
    ):
        assert key in report, key
    gate = report["correctness"]
    assert gate["passed"] and gate["max_relative_deviation"] <= 1e-9
    assert {c["against"] for c in gate["checks"]} >= {"numpy"}
    impls = {row["impl"] for row in report["throughput"]}
    assert {"so3jax", "so3jax-single", "so3jax-all-cores", "numpy"} <= impls
    all_cores = next(r for r in report["throughput"] if r["impl"] == "so3jax-all-cores")
    assert all_cores["batch"] == 2 and 1 <= all_cores["devices"] <= 2
    assert ("numba" in impls) == report["numba_available"]
    if report["numba_available"]:  # timed head to head with Numba, noise given and drawn
        assert set(all_cores["head_to_head"]) == {"numba", "numba-draw"}
        for h2h in all_cores["head_to_head"].values():
            assert len(h2h["so3jax_s"]) == len(h2h["baseline_s"]) >= 5 and h2h["ratio_median"] > 0
        assert "numba-draw" in impls
        for controller in report["summary"].values():
            assert controller["so3jax_all_cores_over_numba_draw_interleaved"] > 0
    for row in report["throughput"]:
        assert row["trajectory_steps_per_s"] > 0 and len(row["runs_s"]) == 3
    assert any(r["baseline"] == "numpy" for r in report["ratios"])
    assert report["step_cost"]["pd"]["float64"]["single"]["flops"] > 1000
    assert report["peak"]["flops_per_s"] > 0
    assert 0 < report["flop_rates"][0]["fraction_of_peak"] < 1
    assert len(report["machine"]["load_avg_start"]) == 3


def test_gate_failure_refuses_to_time(monkeypatch, capsys):
    failing = {"tolerance": 1e-9, "max_relative_deviation": 1e-6, "passed": False, "checks": []}
    monkeypatch.setattr(throughput, "correctness", lambda quick, controllers: failing)
    monkeypatch.setattr(throughput, "so3jax_batched", lambda *a: pytest.fail("timed despite the failed gate"))
    assert throughput.main(["--quick"]) == 1
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["correctness"]["passed"] is False and "throughput" not in report


def test_deviation_is_relative_to_the_largest_entry():
    ours = {"rmse": [1.0, 2.0], "effort": [10.0], "R": [[1.0, 0.0], [0.0, 1.0]]}
    theirs = {"rmse": [1.0, 2.0 + 2e-9], "effort": [10.0], "R": [[1.0, 0.0], [1e-12, 1.0]]}
    dev = throughput._deviation(ours, theirs)
    assert dev["rmse"] == pytest.approx(1e-9, rel=1e-6)
    assert dev["effort"] == 0.0 and dev["R"] == pytest.approx(1e-12)


def test_ratios_pair_equal_controller_batch_and_dtype():
    def row(impl, dtype, batch, rate):
        return {"impl": impl, "controller": "pd", "dtype": dtype, "batch": batch, "trajectory_steps_per_s": rate}

    rows = [
        row("so3jax", "float64", 256, 10.0),
        row("so3jax", "float32", 256, 20.0),
        row("numba", "float64", 256, 5.0),
        row("numpy", "float64", 256, 1.0),
        row("numpy", "float32", 256, 2.0),
        row("so3jax", "float64", 16, 3.0),
    ]
    got = {
        (r["baseline"], r["so3jax_dtype"], r["baseline_dtype"]): r["so3jax_over_baseline"]
        for r in throughput.ratios(rows)
    }
    assert got == {
        ("numba", "float64", "float64"): 2.0,
        ("numba", "float32", "float64"): 4.0,
        ("numpy", "float64", "float64"): 10.0,
        ("numpy", "float32", "float32"): 10.0,
    }


def test_all_parses_indented_or_last_line_json():
    assert bench_all._parse('progress\n{"a": 1}') == {"a": 1}
    assert bench_all._parse('{\n "a": {\n  "b": 2\n }\n}\n') == {"a": {"b": 2}}
    assert bench_all._parse("no json here") is None
    assert bench_all._slug("AMD EPYC 7B13 64-Core") == "amd-epyc-7b13-64-core"


def test_tune_benchmark_interleaves_and_compares_device_counts():
    """benchmarks/tune.py's parent with stand-in children (no compilation): children are
    asked in alternating order, round by round; ratios and value differences are reported."""
    from benchmarks import tune as bench_tune

    asked = []

    class Child:
        def __init__(self, devices, spec):
            self.devices = devices

        def ask(self, op, batch, **kwargs):
            asked.append((op, self.devices))
            if op == "compile":
                return {"compile_s": 1.0, "size": batch or 2, "n_steps": 200, "devices_used": min(self.devices, 2)}
            if op == "run":
                return {"step_s": 0.2 / self.devices, "cpu_s": 0.2}
            return {"cost": 1.0 + 1e-16 * self.devices, "grad": [0.5, -0.25 * self.devices]}

        def close(self):
            pass

    out = bench_tune.measure("tuning/pd_equal_effort.toml", 0.1, [0, 64], [1, 2], rounds=3, calls=1, spawn=Child)
    assert [d for op, d in asked if op == "run"][:6] == [1, 2, 2, 1, 1, 2]
    assert set(out) == {"campaign (2)", "64"}
    row = out["64"]
    assert row["scenarios"] == 64 and row["devices_2"]["batch_split_over"] == 2
    assert row["speedup_2_over_1_rounds"] == [2.0, 2.0, 2.0] and row["speedup_2_over_1_median"] == 2.0
    assert row["max_relative_difference"]["grad"] == 0.5 and row["max_relative_difference"]["cost"] < 1e-15


@pytest.mark.slow
def test_tune_benchmark_smoke():
    """benchmarks/tune.py end to end at a tiny horizon (two child processes; their
    compilations take ~30-60 s here), hence slow."""
    cmd = [sys.executable, str(ROOT / "benchmarks" / "tune.py"), "--T", "0.05", "--batches", "0", "--rounds", "1",
           "--calls", "1", "--devices", "1,2"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    row = report["batches"]["campaign (2)"]
    assert row["devices_1"]["step_s_median"] > 0 and row["devices_2"]["batch_split_over"] == 1
    assert row["max_relative_difference"]["grad"] < 1e-12
    assert "machine" in report and report["command"].startswith("python -m benchmarks.tune")


def _run_benchmark(*args) -> dict:
    """A benchmark module run as committed (``python -m benchmarks.NAME ...``); its JSON report."""
    proc = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, cwd=ROOT, timeout=900,
                          check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout[proc.stdout.index("{"):])


def test_flight_benchmark_runs_as_committed():
    """benchmarks/flight.py at a tiny size: both wirings compile and run under jax.jit (the
    PD: the laws share the programs' code)."""
    report = _run_benchmark("benchmarks.flight", "--batch", "2", "--steps", "20", "--rounds", "1",
                            "--controllers", "pd")
    for controller in ("pd",):
        row = report["rates"][controller]
        assert row["paper"]["M_steps_per_s"] > 0 and row["flight"]["M_steps_per_s"] > 0


def test_sweep_benchmark_runs_as_committed():
    """benchmarks/sweep.py at a tiny size, with the Numba head-to-head and the FLOP count."""
    pytest.importorskip("numba")
    report = _run_benchmark("benchmarks.sweep", "--devices", "1", "--controllers", "pd", "--T", "0.2", "--samples",
                            "8", "--chunk", "8", "--rounds", "1", "--numba", "--flops")
    run = report["runs"][0]
    assert run["trajectory_steps_per_s"] > 0 and run["numba_trajectory_steps_per_s"] > 0
    assert run["numba_rmse_max_rel_diff"] < 1e-12  # the two computed the same samples
    assert 1e3 < run["flops_per_trajectory_step"] < 1e5 and 0 < run["share_of_peak"] < 1
    assert report["full_sweep"]["by_devices"]["1"]["median_trajectory_steps_per_s"]["pd"] > 0


def test_sweep_wall_names_its_file_by_the_cpu():
    from benchmarks.sweep_wall import slug

    assert slug("Intel(R) Xeon(R) Processor") == "intel-xeon"
    assert slug("AMD EPYC 7B13 64-Core Processor") == "amd-epyc-7b13-64core"
    assert slug("Intel(R) Core(TM) i7-1185G7 @ 3.00GHz") == "intel-core-i71185g7"


@pytest.mark.slow
def test_sweep_wall_runs_as_committed(tmp_path):
    """benchmarks/sweep_wall.py on a tiny sweep: a cold and a warm run of the installed command."""
    report = _run_benchmark("benchmarks.sweep_wall", "--out", str(tmp_path / "wall.json"), "--sweep-args",
                            "--samples", "8", "--T", "0.2", "--controllers", "pd")
    assert [r["cache"] for r in report["runs"]] == ["cold", "warm"]
    assert all(r["wall_s"] > 0 for r in report["runs"]) and report["cpu"]


@pytest.mark.slow
def test_sweep_profile_runs_as_committed():
    report = _run_benchmark("benchmarks.sweep_profile", "--batch", "8", "--T", "0.05", "--rounds", "1",
                            "--controllers", "pd")
    assert len(report["rows"]) == 8 and all(r["trajectory_steps_per_s"] > 0 for r in report["rows"])
    assert {r["variant"] for r in report["rows"]} >= {"dispersed", "library trigonometry"}


@pytest.mark.slow  # a reverse-mode program of its own (~20 s of compilation); the gradients: tests/test_gradients.py
@pytest.mark.parametrize("mission", [(), pytest.param(("--mission", "missions/flight.toml"), marks=pytest.mark.slow)],
                         ids=["paper", "flight"])
def test_gradients_benchmark_runs_as_committed(mission):
    report = _run_benchmark("benchmarks.gradients", "--controllers", "pd", "--horizons", "20", "--batch", "2",
                            "--modes", "forward", "--fd-horizon", "0", *mission)
    rows = [r for r in report["runs"] if r.get("what") == "forward"]
    assert rows and all(np.all(np.isfinite(r["gradient"])) for r in rows)
    assert not any("error" in r for r in report["runs"])


def test_limit_surrogate_clip_is_the_clip_smoothed_over_its_width():
    """benchmarks/limit_surrogate.py's smoothed motor torque limit: within w log 2 of the
    clip everywhere, equal to it (to e^-10 w) more than 10 w inside or outside the limits."""
    import jax.numpy as jnp

    from benchmarks.limit_surrogate import _smooth_wheels
    from so3jax.components.actuators import Wheels, pyramid_axes

    wheels = Wheels(jnp.asarray(pyramid_axes(4), float), jnp.full(4, 0.16), jnp.full(4, 0.05), jnp.full(4, 628.0),
                    jnp.zeros(4), momentum_compensation=False)
    smooth = _smooth_wheels(wheels, 0.1)
    rng = np.random.default_rng(0)
    tau = jnp.asarray(rng.normal(scale=0.06, size=(3, 4000)))
    state, omega = jnp.zeros((4, 4000)), jnp.zeros((3, 4000))
    exact, smoothed = wheels.command(state, tau, omega).u, smooth.command(state, tau, omega).u
    wanted = np.asarray(wheels.distribute(tau))
    w = 0.1 * 0.05
    gap = np.abs(np.asarray(smoothed - exact))
    assert gap.max() <= w * np.log(2) * (1 + 1e-12) and gap.max() > 0.5 * w * np.log(2)  # the corner is reached
    far = np.abs(np.abs(wanted) - 0.05) > 10 * w
    assert far.any() and (~far).any() and gap[far].max() <= np.exp(-10) * w


@pytest.mark.slow
def test_limit_surrogate_benchmark_runs_as_committed():
    report = _run_benchmark("benchmarks.limit_surrogate", "--T", "2", "--iterations", "1", "--laws", "pd",
                            "--seeds", "1")
    runs = report["laws"]["pd"]
    assert runs["exact"][0]["exact_train"] == runs["surrogate"][0]["exact_train"] == pytest.approx(2.0, rel=1e-12)
    assert all(np.isfinite(r["exact_held_out"]) for rows in runs.values() for r in rows)


# A while loop of 10 iterations: two fusions, a copy and an add per iteration, a compare per
# condition (11 evaluations); in the entry a command buffer of one fusion, and a copy.
HLO = """HloModule m, entry_computation_layout={(f64[4]{0})->f64[4]{0}}

%fused_sine (p: f64[4]) -> f64[4] {
  %p = f64[4]{0} parameter(0)
  ROOT %s = f64[4]{0} sine(f64[4]{0} %p)
}

%body (t: (s32[], f64[4])) -> (s32[], f64[4]) {
  %t = (s32[], f64[4]{0}) parameter(0)
  %i = s32[] get-tuple-element((s32[], f64[4]{0}) %t), index=0
  %x = f64[4]{0} get-tuple-element((s32[], f64[4]{0}) %t), index=1
  %f1 = f64[4]{0} fusion(f64[4]{0} %x), kind=kLoop, calls=%fused_sine
  %f2 = f64[4]{0} fusion(f64[4]{0} %f1), kind=kLoop, calls=%fused_sine
  %c = f64[4]{0} copy(f64[4]{0} %f2)
  %one = s32[] constant(1)
  %n = s32[] add(s32[] %i, s32[] %one)
  ROOT %r = (s32[], f64[4]{0}) tuple(s32[] %n, f64[4]{0} %c)
}

%cond (t: (s32[], f64[4])) -> pred[] {
  %t = (s32[], f64[4]{0}) parameter(0)
  %i = s32[] get-tuple-element((s32[], f64[4]{0}) %t), index=0
  %k = s32[] constant(10)
  ROOT %lt = pred[] compare(s32[] %i, s32[] %k), direction=LT
}

%command_buffer (p: f64[4]) -> f64[4] {
  %p = f64[4]{0} parameter(0)
  ROOT %f = f64[4]{0} fusion(f64[4]{0} %p), kind=kLoop, calls=%fused_sine
}

ENTRY %main (x: f64[4]) -> f64[4] {
  %x = f64[4]{0} parameter(0)
  %b = f64[4]{0} call(f64[4]{0} %x), to_apply=%command_buffer
  %z = s32[] constant(0)
  %t = (s32[], f64[4]{0}) tuple(s32[] %z, f64[4]{0} %b)
  %w = (s32[], f64[4]{0}) while(%t), condition=%cond, body=%body, backend_config={"known_trip_count":{"n":"10"}}
  %o = f64[4]{0} get-tuple-element((s32[], f64[4]{0}) %w), index=1
  ROOT %y = f64[4]{0} copy(f64[4]{0} %o)
}
"""


def test_gpu_launches_weights_each_computation_by_its_trip_count():
    """benchmarks/gpu.py's count of kernel launches, on HLO whose launches are known: per step
    (10 steps) 2 fusions in the body and 0.1 in the entry's command buffer; 1 copy and 1 add in
    the body, 1.1 compare in the condition, 0.1 copy in the entry; a fusion's own computation
    never counts."""
    got = gpu.launches(HLO, n_steps=10)
    assert got["fusions_per_step"] == pytest.approx(2.1)
    assert got["other_ops_per_step"] == pytest.approx({"add": 1.0, "compare": 1.1, "copy": 1.1})
    assert got["launches_per_step"] == pytest.approx(5.3)
    assert got["in_command_buffers_per_step"] == pytest.approx(0.1)
    assert got["while_iterations_per_step"] == pytest.approx(1.0)
    assert got["while_loops_without_trip_count"] == 0
    assert got["innermost_loop"]["launches_per_iteration"] == 4 and got["innermost_loop"]["trip_count"] == 10


def test_gpu_launches_reads_this_xla_s_compiled_text():
    """On a program this JAX compiles, a loop of 7 iterations over 7 steps: one while
    iteration per step, found with its trip count (the text's format as the parser reads it)."""
    import jax
    import jax.numpy as jnp

    text = jax.jit(lambda x: jax.lax.fori_loop(0, 7, lambda i, v: jnp.sin(v) * v[::-1], x)).lower(
        jnp.ones(5)).compile().as_text()
    got = gpu.launches(text, n_steps=7)
    assert got["while_iterations_per_step"] == pytest.approx(1.0)
    assert got["while_loops_without_trip_count"] == 0 and got["launches_per_step"] >= 1.0


def test_gpu_trace_summary_counts_xla_s_events_per_step(tmp_path):
    """A traced run of a jitted loop: the summary finds the host plane's XLA events (a CPU has no
    device plane) and divides by the steps given."""
    import jax
    import jax.numpy as jnp

    f = jax.jit(lambda x: jax.lax.fori_loop(0, 20, lambda i, v: jnp.sin(v) * v[::-1], x))
    x = jnp.ones(64)
    jax.block_until_ready(f(x))
    with jax.profiler.trace(str(tmp_path)):
        jax.block_until_ready(f(x))
    got = gpu.trace_summary(str(tmp_path), n_steps=20)
    assert got["planes"] == ["/host:CPU"]
    assert got["events_per_step"] > 0 and got["top"] and got["span_us_per_step"] > 0
    assert sum(t["per_step"] for t in got["top"]) <= got["events_per_step"] + 1e-12
    assert gpu.trace_summary(str(tmp_path / "empty"), 1) == {"trace": "no xplane written"}
    assert gpu.trace_summary(str(tmp_path), 20, device_expected=True)["trace"].startswith("no device plane")


def test_gpu_report_checks_each_goal_against_its_limit():
    """The record's report: a goal is met only by a measurement within its limit (the default
    sweep's only at its own size, without overrides); an unmeasured goal is neither."""
    steps = lambda rate, unroll: {"part": "steps", "loop": "paper", "batch": 65536, "unroll": unroll,
                                  "variant": "default", "us_per_step": 1.0, "trajectory_steps_per_s": rate}
    sweep = lambda loop_s, overrides: {"part": "sweep", "name": "default-warm", "precision": "float64",
                                       "cache": "warm", "chunk": 1024, "sweep_loop_s": loop_s,
                                       "trajectory_steps_per_s": 1e9, "overrides": overrides}
    goals = lambda rows: [line for line in gpu.report({"measurements": rows}).splitlines()
                          if line.startswith(("| default sweep", "| PD, paper", "| 1e5 flight"))]
    met = lambda rows: [line.split(" | ")[3] for line in goals(rows)]
    assert met([]) == ["–", "–", "–"]
    assert met([sweep(4.9, []), steps(1.5e9, 1), steps(2.1e9, 4)])[:2] == ["yes", "yes"]
    assert "unroll 4" in goals([steps(1.5e9, 1), steps(2.1e9, 4)])[1]
    assert met([sweep(5.1, []), steps(1.9e9, 1)])[:2] == ["no", "no"]
    assert met([sweep(1.0, ["sweep.samples=16"])])[0] == "no"
    flight = {"part": "flight", "name": "slice-1e5", "full_run_s_extrapolated": 590.0, "n_steps": 2000, "chunk": 8}
    assert met([flight])[2] == "yes" and met([{**flight, "full_run_s_extrapolated": 610.0}])[2] == "no"
