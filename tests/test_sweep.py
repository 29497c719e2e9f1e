"""Parameter sweeps: study files, G-code rewrites, the job runner, and a tiny study on a
2-worker Dask LocalCluster (failure isolation, resume, --retry-failed, Ctrl-C)."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from taichi_mex import bundled
from taichi_mex.app.cli import main
from taichi_mex.errors import UserInputError
from taichi_mex.toolpath.generate import bead_area_mm2, scale_words, write_pattern, write_scaled
from taichi_mex.app.jobs import check_names, key_metrics, resolve
from taichi_mex.toolpath.plan import make_plan
from taichi_mex.app.sweep import load_study, plot_metric, run_name, write_results

REPO = Path(__file__).resolve().parent.parent
TINY = REPO / "examples" / "study_tiny.toml"


def write_study(tmp_path, text: str, name: str = "study.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# --------------------------------------------------------------------------- G-code
def test_generated_bead_and_block_match_the_bundled_files(tmp_path):
    bead = write_pattern(tmp_path / "bead.gcode", pattern="bead", layer_height_mm=0.2,
                         line_width_mm=0.45, speed_mm_s=60, bead_length_mm=5)
    mine, ref = make_plan(bead).as_dict(), make_plan(bundled.gcode_path("single_bead")).as_dict()
    for key in ("print_time_s", "extruded_volume_mm3", "selected_time_window_s", "layer_z_mm"):
        assert mine[key] == pytest.approx(ref[key], rel=1e-4)
    assert ref["extruded_volume_mm3"] == pytest.approx(5 * bead_area_mm2(0.45, 0.2), rel=1e-4)
    block = write_pattern(tmp_path / "block.gcode", pattern="block", beads=3, layers=3)
    mine, ref = make_plan(block).as_dict(), make_plan(bundled.gcode_path("block_3x3")).as_dict()
    assert mine["n_layers"] == ref["n_layers"] == 3
    assert mine["extruded_volume_mm3"] == pytest.approx(ref["extruded_volume_mm3"], rel=1e-4)
    with pytest.raises(UserInputError, match="at least as wide"):
        write_pattern(tmp_path / "bad.gcode", line_width_mm=0.1, layer_height_mm=0.2)


def test_feed_rate_rewrite_touches_only_feed_rates(tmp_path):
    text = ("N10 G1 X10 F3600*33\ng1 x1 f100 ; F200 stays\nM117 F100 stays\n"
            "G1 E-0.8 F2100\n;F5\nG01 F3600 (F1) ; c\nM204 P1250\n")
    out, n = scale_words(text, "F", 2.0)
    lines = out.splitlines()
    assert n == 4
    body = "N10 G1 X10 F7200"
    checksum = 0
    for ch in body.encode():
        checksum ^= ch
    assert lines[0] == f"{body}*{checksum}"
    assert lines[1] == "g1 x1 f200 ; F200 stays"
    assert lines[2] == "M117 F100 stays" and lines[4] == ";F5" and lines[6] == "M204 P1250"
    assert lines[3] == "G1 E-0.8 F4200"
    assert lines[5] == "G01 F7200 (F1) ; c"
    slow = write_scaled(bundled.gcode_path("single_bead"), tmp_path / "slow.gcode", feed_rate_factor=0.5)
    ref = make_plan(bundled.gcode_path("single_bead")).as_dict()
    got = make_plan(slow).as_dict()
    assert got["extruded_volume_mm3"] == pytest.approx(ref["extruded_volume_mm3"], rel=1e-6)
    assert got["extruding_time_s"] > 1.3 * ref["extruding_time_s"]  # accelerations cap the ratio
    more = write_scaled(bundled.gcode_path("single_bead"), tmp_path / "more.gcode", flow_factor=1.2)
    assert make_plan(more).as_dict()["extruded_volume_mm3"] == pytest.approx(
        1.2 * ref["extruded_volume_mm3"], rel=1e-4)
    (tmp_path / "nof.gcode").write_text("G1 X1 Y1\n")
    with pytest.raises(UserInputError, match="no F words"):
        write_scaled(tmp_path / "nof.gcode", tmp_path / "x.gcode", feed_rate_factor=2)


# --------------------------------------------------------------------------- parameters
def test_unknown_names_are_refused_up_front(tmp_path, capsys):
    with pytest.raises(UserInputError, match="did you mean 'viscosity'"):
        check_names({"visocsity": 1.0})
    with pytest.raises(UserInputError, match="sound_speed_m_s"):
        check_names({"run.edac.sound_speed": 6.0})
    with pytest.raises(UserInputError, match="group of options"):
        check_names({"run.edac": 1})
    check_names({"run.edac.cfl": 0.2, "material.emissivity": 0.9, "viscosity": 1.0})
    study = write_study(tmp_path, '[base]\ngcode = "paper_bead"\n[grid]\nvisocsity = [1, 2]\n')
    assert main(["sweep", str(study), "--out", str(tmp_path / "out")]) == 2
    assert "did you mean 'viscosity'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    bad_plot = write_study(tmp_path, '[grid]\nviscosity = [1, 2]\n[plot]\nmetric = "width"\n'
                                     'param = "viscosity"\n', "p.toml")
    assert main(["sweep", str(bad_plot), "--out", str(tmp_path / "out")]) == 2
    assert "Cannot plot 'width'" in capsys.readouterr().err


def test_study_expansion_and_stable_run_names(tmp_path):
    study = load_study(write_study(tmp_path, """
[base]
gcode = "single_bead"
spacing_mm = 0.1
[grid]
feed_rate_factor = [0.5, 1, 2]
viscosity = [1, 10]
[[runs]]
scheme = "dfsph"
run.edac.cfl = 0.2
"""))
    assert len(study.runs) == 7
    assert study.runs[-1].params["run.edac.cfl"] == 0.2  # TOML dotted keys, flattened back
    assert study.varied == ["feed_rate_factor", "viscosity", "scheme", "run.edac.cfl"]
    names = [r.name for r in study.runs]
    assert len(set(names)) == 7 and names[0].startswith("feed_rate_factor=0.5_viscosity=1-")
    assert [r.name for r in load_study(study.path).runs] == names
    params = study.runs[1].params
    assert run_name({**params, "viscosity": 10.0}, study.varied) == run_name(
        {**params, "viscosity": 10}, study.varied)
    assert run_name({**params, "spacing_mm": 0.2}, study.varied) != names[1]


def test_resolve_builds_options_and_refuses_bad_values(tmp_path):
    res = resolve({"preset": "paper", "spacing_mm": 0.12, "viscosity": 3.0, "sound_speed": 10,
                   "nozzle_temperature_c": 230, "feed_rate_factor": 1.5, "layers": 1,
                   "run.edac.cfl": 0.2})
    run, material, options = res.spec.run, res.spec.material, res.spec.options
    assert run.scheme == "edac" and run.spacing_mm == 0.12 and run.edac.cfl == 0.2
    assert run.edac.sound_speed_m_s == 10 and not run.thermal.enabled
    assert material.viscosity_pa_s == 3.0 and material.extrusion_temperature_c == 230
    assert options.gcode.endswith("paper_bead.gcode") and res.feed_rate_factor == 1.5
    assert options.nozzle_height == "one_diameter"
    assert options.nozzle_tip_outer_diameter_mm is None
    assert options.layers == 1
    # a study written before the run description: scene.OPTION for a run option still works
    legacy = resolve({"scene": "thermal-beam", "scene.surface_method": "eigenvalue", "scene.until": 5})
    assert legacy.spec.run.thermal.surface_method == "eigenvalue" and legacy.spec.options.until_s == 5
    gen = resolve({"layer_height_mm": 0.3, "speed_mm_s": 40})
    assert gen.generate["pattern"] == "bead"
    for params, message in (({"spacing_mm": 500.0}, "outside"),
                            ({"plate_temperature_c": 60, "thermal": False}, "need heat"),
                            ({"gcode": "paper_bead", "speed_mm_s": 40}, "generated G-code"),
                            ({"gcode": "nope"}, "neither a file"),
                            ({"viscosity": "thick"}, "should be a number"),
                            ({"until": 1.0, "deposit_for_s": 0.1}, "not both"),
                            ({"run.dfsph.max_travel_spacings": -0.5}, "max_travel_spacings"),
                            ({"run.dfsph.step_retries": -1}, "step_retries")):
        with pytest.raises(UserInputError, match=message):
            resolve(params)


def test_results_table_and_plot_from_records(tmp_path):
    study = load_study(write_study(tmp_path, '[grid]\nviscosity = [1, 2, 3]\nscheme = ["edac", "dfsph"]\n'))
    runs_dir = tmp_path / "out" / "runs"
    for i, run in enumerate(study.runs):
        folder = runs_dir / run.name
        folder.mkdir(parents=True)
        failed = i == 5
        record = {"run": run.name, "params": run.params, "status": "failed" if failed else "done",
                  "metrics": {} if failed else {"bead_width_mm": 0.4 + 0.01 * i, "wall_time_s": 2.0},
                  "summary": {"steps": 10}}
        if failed:
            record.update(failure="diverged", error="blew up\nsecond line")
        (folder / "job.json").write_text(json.dumps(record))
        (folder / "summary.json").write_text("{}")
    paths = write_results(study, tmp_path / "out")
    rows = list(csv.DictReader(paths["csv"].open()))
    assert [r["run"] for r in rows] == [r.name for r in study.runs]
    assert rows[0]["bead_width_mm"] == "0.4" and rows[0]["viscosity"] == "1"
    assert rows[5]["status"] == "failed" and rows[5]["error"] == "blew up"
    assert rows[0]["steps"] == "10"  # from the summary when the metrics lack it
    failures = json.loads(paths["failures"].read_text())
    assert len(failures) == 1 and failures[0]["failure"] == "diverged"
    if "parquet" in paths:
        import pyarrow.parquet as pq

        table = pq.read_table(paths["parquet"])
        assert table.num_rows == 6 and str(table.schema.field("bead_width_mm").type) == "double"
    from taichi_mex.app.sweep import collect_rows

    png = plot_metric(collect_rows(study, runs_dir), "bead_width_mm", "viscosity", study.varied,
                      tmp_path / "plot.png")
    assert png.stat().st_size > 1000
    assert key_metrics({"particles_active": 5}, {"sections": [{"mean_width_mm": 0.5,
                                                               "void_fraction": 0.1}]}) == {
        "particles": 5.0, "bead_width_mm": 0.5, "void_fraction": 0.1}


# --------------------------------------------------------------------------- Dask
def _records(out: Path) -> dict:
    return {p.parent.name: json.loads(p.read_text()) for p in (out / "runs").glob("*/job.json")}


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "tiny"
    t0 = time.perf_counter()
    rc = main(["sweep", str(TINY), "--out", str(out), "--workers", "2", "--quiet"])
    return out, rc, time.perf_counter() - t0


def test_tiny_study_on_two_workers_records_failures_and_goes_on(tiny_sweep):
    out, rc, wall = tiny_sweep
    assert rc == 1  # some runs failed, all were attempted
    records = _records(out)
    assert len(records) == 4
    by_failure = {r.get("failure"): r for r in records.values()}
    assert "spacing_mm = 500.0 is outside [0.001, 100]" in by_failure["refused"]["error"]
    assert "blew up" in by_failure["diverged"]["error"]
    done = [r for r in records.values() if r["status"] == "done"]
    assert {r["params"]["viscosity"] for r in done} == {0.1, 0.2}
    for r in done:
        folder = out / "runs" / r["run"]
        assert (folder / "particles.h5").is_file() and (folder / "summary.json").is_file()
        assert r["metrics"]["steps"] > 100 and r["metrics"]["commanded_volume_mm3"] > 0
        assert r["cpu_threads"] == max(1, len(os.sched_getaffinity(0)) // 2)
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == 4 and {"viscosity", "spacing_mm", "bead_width_mm", "void_fraction",
                               "density_error_mean", "cooling_time_s", "wall_time_s"} <= rows[0].keys()
    assert sorted(r["status"] for r in rows) == ["done", "done", "failed", "failed"]
    assert len(json.loads((out / "failures.json").read_text())) == 2
    index = (out / "index.html").read_text()  # the sweep's page: every run, linked to its report
    assert all(r["run"] in index for r in rows) and "runs/" in index
    assert (out / "plot_sim_wall_time_s_vs_viscosity.png").is_file()


def test_rerun_resumes_and_retry_failed_retries(tiny_sweep, capsys):
    out, _, _ = tiny_sweep
    before = _records(out)
    h5_times = {name: (out / "runs" / name / "particles.h5").stat().st_mtime_ns
                for name, r in before.items() if r["status"] == "done"}
    assert main(["sweep", str(TINY), "--out", str(out), "--workers", "2", "--quiet"]) == 1
    text = capsys.readouterr().out
    assert "(0 run now, 2 finished earlier" in text
    assert _records(out) == before
    assert main(["sweep", str(TINY), "--out", str(out), "--workers", "2", "--quiet",
                 "--retry-failed"]) == 1
    after = _records(out)
    for name, r in after.items():
        if r["status"] == "done":
            assert r == before[name]
            assert (out / "runs" / name / "particles.h5").stat().st_mtime_ns == h5_times[name]
        else:
            assert r["finished"] >= before[name]["finished"] and r != before[name]


def test_ctrl_c_keeps_finished_runs(tmp_path):
    """SIGINT to the whole process group, as a terminal's Ctrl-C sends it."""
    study = write_study(tmp_path, """
[base]
gcode = "paper_bead"
preset = "paper"
spacing_mm = 0.12
deposit_for_s = 0.008
snapshots = false
analysis = false
[grid]
dt_factor = [1.0, 0.01]   # the second run takes minutes: it is still running at Ctrl-C
""")
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "taichi_mex", "sweep", str(study), "--out", str(out),
                             "--workers", "1", "--quiet"], start_new_session=True,
                            # SIGINT may be ignored in a suite started in the background
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # Ctrl-C once the first run is done and the second has started (its job process
        # wrote params.json): under load the second once had not started 2 s after the
        # first was done, and a run never started is rightly 'pending'
        deadline = time.time() + 240
        ready = False
        while time.time() < deadline and proc.poll() is None:
            done = [n for n, r in _records(out).items() if r["status"] == "done"]
            started = [p.parent.name for p in (out / "runs").glob("*/params.json")]
            if done and set(started) - set(done):
                ready = True
                break
            time.sleep(0.5)
        seen = {n: r["status"] for n, r in _records(out).items()}  # what the Ctrl-C met
        os.killpg(proc.pid, signal.SIGINT)
        text, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    # every message carries the sweep's output and the records before and after the Ctrl-C:
    # a failure here once left nothing to read (2026-12-04)
    records = _records(out)
    said = f"records at Ctrl-C {seen}, after {records}; output:\n{text}"
    assert ready, "the second run never started beside a finished first one: " + said
    assert proc.returncode == 130, said
    assert "Traceback" not in text, said
    assert sorted(r["status"] for r in records.values()) == ["done", "interrupted"], said
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert sorted(r["status"] for r in rows) == ["done", "interrupted"], f"{rows}; " + said


def test_after_ctrl_c_a_run_started_without_a_record_is_interrupted(tmp_path):
    """The race behind two CI failures, without timing: a run this sweep started whose job
    process wrote no record (Ctrl-C during its start-up) is written as interrupted once the
    grace is over; a run of another batch, or one with a final record, is left alone."""
    from types import SimpleNamespace

    from taichi_mex.app import jobs
    from taichi_mex.app.sweep import _await_records

    runs = [SimpleNamespace(name=n, params={"k": i}) for i, n in enumerate("abcd")]
    for r, batch in zip(runs, ["now", "now", "earlier", None]):
        (tmp_path / r.name).mkdir()
        if batch is not None:
            jobs.write_json_atomic(tmp_path / r.name / jobs.PARAMS_FILE, {"params": r.params, "batch": batch})
    jobs.write_json_atomic(tmp_path / "b" / jobs.JOB_FILE, {"run": "b", "status": "done"})
    jobs.write_json_atomic(tmp_path / "c" / jobs.JOB_FILE, {"run": "c", "status": "running"})
    said = []
    _await_records(runs, tmp_path, "now", echo=said.append, grace_s=0.3)
    assert jobs.read_record(tmp_path / "a")["status"] == "interrupted"
    assert jobs.read_record(tmp_path / "a")["params"] == {"k": 0}
    assert jobs.read_record(tmp_path / "b")["status"] == "done"
    assert jobs.read_record(tmp_path / "c")["status"] == "running"  # another sweep's
    assert jobs.read_record(tmp_path / "d") is None  # never started
    assert said == ["waiting up to 0 s for 1 interrupted run(s) to stop"]


def test_ctrl_c_during_the_taichi_import_is_held_back_until_it_is_done():
    """A job imports Taichi with Ctrl-C held back (jobs.sigint_deferred): Taichi turns an
    interrupted library load into ImportError, and a sweep's Ctrl-C in that moment recorded
    the run as failed (CI, 2026-12-03). The signal sent inside the block arrives as
    KeyboardInterrupt when the block ends, not during it; a fresh process, as a job is."""
    code = (
        "import os, signal\n"
        "from taichi_mex.app.jobs import sigint_deferred\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "reached = False\n"
        "try:\n"
        "    with sigint_deferred():\n"
        "        os.kill(os.getpid(), signal.SIGINT)\n"
        "        reached = True\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted after the block:', reached)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "interrupted after the block: True", out.stdout + out.stderr


def test_ctrl_c_a_library_turns_into_its_own_error_is_an_interruption(tmp_path):
    """Taichi's kernel decorator, reading annotations when a sweep's Ctrl-C fell, raised
    TaichiSyntaxError and the run was recorded as failed (a suite run, 2026-12-04). A job that
    received Ctrl-C is interrupted whatever error it ends with; an error without one is a
    failure. A fresh process, as a job is; the library is a stand-in that swallows the
    KeyboardInterrupt."""
    code = (
        "import os, signal, sys\n"
        "from taichi_mex.app import jobs\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "def library(params, base_dir):\n"
        "    try:\n"
        "        if sys.argv[2] == 'ctrl-c':\n"
        "            os.kill(os.getpid(), signal.SIGINT)\n"
        "    except KeyboardInterrupt:\n"
        "        pass\n"
        "    raise SyntaxError('parameters must be type annotated')\n"
        "jobs.resolve = library\n"
        "print(jobs.run_print_job({}, sys.argv[1])['status'])\n")
    for how, status in (("ctrl-c", "interrupted"), ("none", "failed")):
        out = subprocess.run([sys.executable, "-c", code, str(tmp_path / how), how],
                             capture_output=True, text=True, timeout=120)
        assert out.stdout.strip().splitlines()[-1] == status, out.stdout + out.stderr


@pytest.mark.parametrize("example", sorted(p.name for p in (REPO / "examples").glob("study_*.toml")))
def test_example_studies_are_valid(example, tmp_path, capsys):
    assert main(["sweep", str(REPO / "examples" / example), "--dry-run", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    refused = text.count("would be refused")
    assert refused == (1 if example == "study_tiny.toml" else 0), text


def test_isolated_job_past_its_time_limit_is_recorded(tmp_path):
    from taichi_mex.app.jobs import run_job_isolated

    # tens of thousands of explicit steps: no machine finishes this inside the limit
    record = run_job_isolated({"gcode": "paper_bead", "preset": "paper", "spacing_mm": 0.05,
                               "deposit_for_s": 0.13, "snapshots": False}, tmp_path / "run",
                              timeout_s=3)
    assert record["status"] == "failed" and record["failure"] == "timeout"
    assert json.loads((tmp_path / "run" / "job.json").read_text())["failure"] == "timeout"


def test_runs_keep_their_folders_when_the_study_grows(tmp_path):
    from taichi_mex.app.sweep import adopt_renamed

    base = '[base]\ngcode = "paper_bead"\nspacing_mm = 0.1\n[grid]\nviscosity = [1, 2]\n'
    study = load_study(write_study(tmp_path, base))
    runs_dir = tmp_path / "out" / "runs"
    for run in study.runs:
        (runs_dir / run.name).mkdir(parents=True)
        (runs_dir / run.name / "job.json").write_text(json.dumps({"run": run.name, "status": "done"}))
    grown = load_study(write_study(tmp_path, base + '[[runs]]\nviscosity = 3\nspacing_mm = 0.2\n'))
    assert grown.runs[0].name != study.runs[0].name  # spacing_mm is varied now
    assert adopt_renamed(grown, runs_dir) == 2
    for run in grown.runs[:2]:
        assert json.loads((runs_dir / run.name / "job.json").read_text())["run"] == run.name
    assert sorted(p.name for p in runs_dir.iterdir()) == sorted(r.name for r in grown.runs[:2])


def test_bead_ladder_error_is_against_the_creeping_flow_section():
    """The bead ladder's error is a physical one: the section against the rounded rectangle
    at the gap with the commanded area (0.45 x 0.2 mm line: W 0.450, H 0.2, 0.08142 mm^2),
    not against the finest run, which may converge to a wrong shape."""
    from taichi_mex.app.study import _bead_errors

    exact = {"status": "done", "bead_width_mm": 0.45, "bead_height_mm": 0.2,
             "bead_material_area_mm2": 0.081416}
    wide = {**exact, "bead_width_mm": 0.495, "bead_height_mm": 0.19}
    failed = {"status": "failed"}
    rows = [exact, wide, failed]
    _bead_errors("bead", rows)
    assert exact["error"] < 1e-4
    assert wide["error"] == pytest.approx(0.10, abs=1e-3)  # the width's +10 %, over H's -5 %
    assert "creeping-flow" in wide["error_kind"]
    assert "error" not in failed
