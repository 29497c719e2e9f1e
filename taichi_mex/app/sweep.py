"""Parameter studies on Dask distributed: ``python -m taichi_mex sweep STUDY.toml --out DIR``.

A study file (TOML) names what every run shares and what varies::

    [study]
    name = "speed"                       # optional; also: description, metrics = [...]
    [base]                               # every run
    gcode = "paper_bead"
    preset = "paper"
    spacing_mm = 0.1
    deposit_for_s = 0.05
    [grid]                               # the Cartesian product of these lists
    feed_rate_factor = [0.5, 1.0, 1.5]
    viscosity = [0.1, 1.0]
    [[runs]]                             # and/or explicit runs, each over [base]
    scheme = "dfsph"
    [sweep]                              # optional defaults for the command line
    workers = 4
    timeout_s = 3600
    [plot]                               # optional: a metric against a parameter
    metric = "bead_width_mm"
    param = "feed_rate_factor"

Each run gets a folder ``DIR/runs/NAME`` whose name is derived from its parameter values
(readable ``key=value`` parts plus a hash of all of them), so re-running the command finds
the runs already done and skips them. The sweep writes ``DIR/results.csv`` (and
``results.parquet`` when pyarrow is importable), ``DIR/failures.json`` and the plots.

Without ``--scheduler`` a :class:`distributed.LocalCluster` of one single-threaded worker
process per concurrent run is started; each run is a fresh ``python -m taichi_mex.app.jobs``
process (Taichi keeps global state) with the host's cores divided among the runs. With
``--scheduler ADDRESS`` the same runs go to an existing Dask cluster, whose workers must
see ``DIR`` and the study's files at the same paths (a shared file system).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import itertools
import json
import logging
import re
import signal
import sys
import time
import tomllib
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from taichi_mex.app import jobs
from taichi_mex.app.parsing import Parser
from taichi_mex.errors import UserInputError

SECTIONS = ("study", "base", "grid", "runs", "sweep", "plot")
SWEEP_KEYS = ("workers", "threads_per_run", "timeout_s")
#: columns of the results table that come before the parameters
LEAD_COLUMNS = ("run", "status")
TAIL_COLUMNS = ("failure", "error", "folder")


@dataclass
class Run:
    name: str
    params: dict
    #: the values of the study's varied parameters (its table row)
    varied: dict


@dataclass
class Study:
    path: Path
    name: str
    description: str
    runs: list[Run]
    varied: list[str]
    settings: dict = field(default_factory=dict)
    plots: list[tuple[str, str]] = field(default_factory=list)
    extra_metrics: list[str] = field(default_factory=list)

    @property
    def base_dir(self) -> Path:
        return self.path.parent.resolve()

    @property
    def metrics(self) -> list[str]:
        return list(jobs.METRICS) + [m for m in self.extra_metrics if m not in jobs.METRICS]


# --------------------------------------------------------------------------- study files
def _as_list(name: str, value) -> list:
    if isinstance(value, list):
        if not value:
            raise UserInputError(f"[grid] {name} is an empty list: give at least one value.")
        return value
    return [value]


def _canonical(value):
    """Hashable, type-stable form: 60 and 60.0 name the same run."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value
    return float(value)


def _value_text(value) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return format(value, ".6g")
    if isinstance(value, str) and ("/" in value or value.endswith(".gcode")):
        return Path(value).stem
    return str(value)


def run_name(params: dict, varied: list[str]) -> str:
    """Stable folder name: 'key=value' parts of the varied parameters and a hash of all."""
    canonical = json.dumps({k: _canonical(v) for k, v in params.items()}, sort_keys=True)
    digest = hashlib.sha1(canonical.encode()).hexdigest()[:8]
    parts = [f"{k.split('.')[-1]}={_value_text(params[k])}" for k in varied if k in params]
    readable = re.sub(r"[^A-Za-z0-9._=+-]", "_", "_".join(parts))[:80].strip("_")
    return f"{readable}-{digest}" if readable else f"run-{digest}"


def _flatten(table: dict, prefix: str = "") -> dict:
    """TOML's dotted keys (run.edac.cfl = 0.2) arrive as nested tables: flatten them back
    into the parameter names ('run.edac.cfl'); quoted names pass through."""
    out = {}
    for key, value in table.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def load_study(path) -> Study:
    """Read and check a study file: unknown sections, keys and parameter names are refused
    here, before any run starts."""
    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"Study file {path} does not exist.")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise UserInputError(f"{path} is not valid TOML: {exc}") from None
    unknown = sorted(set(data) - set(SECTIONS))
    if unknown:
        raise UserInputError(f"{path}: unknown section(s) {', '.join(unknown)}; a study has "
                             f"{', '.join(SECTIONS)}.")
    for section in ("study", "base", "grid", "sweep", "plot"):
        if section in data and not isinstance(data[section], (dict, list)):
            raise UserInputError(f"{path}: [{section}] must be a table.")
    head = data.get("study", {})
    extra = sorted(set(head) - {"name", "description", "metrics"})
    if extra:
        raise UserInputError(f"{path}: [study] takes name, description and metrics, not "
                             f"{', '.join(extra)}. Parameters shared by every run go in [base].")
    base = _flatten(data.get("base", {}))
    grid = {k: _as_list(k, v) for k, v in _flatten(data.get("grid", {})).items()}
    listed = data.get("runs", [])
    if not isinstance(listed, list) or not all(isinstance(r, dict) for r in listed):
        raise UserInputError(f"{path}: write explicit runs as [[runs]] tables.")
    listed = [_flatten(r) for r in listed]
    settings = dict(data.get("sweep", {}))
    bad = sorted(set(settings) - set(SWEEP_KEYS))
    if bad:
        raise UserInputError(f"{path}: [sweep] takes {', '.join(SWEEP_KEYS)}, not {', '.join(bad)}.")

    combos: list[dict] = []
    if grid or not listed:
        keys = list(grid)
        for values in itertools.product(*(grid[k] for k in keys)):
            combos.append({**base, **dict(zip(keys, values))})
    combos += [{**base, **r} for r in listed]
    for params in combos:
        jobs.check_names(params)

    varied: list[str] = [k for k in grid if len(grid[k]) > 1]
    for key in dict.fromkeys(k for r in listed for k in r):
        values = {json.dumps(_canonical(p.get(key)), sort_keys=True) for p in combos}
        if len(values) > 1 and key not in varied:
            varied.append(key)
    runs: list[Run] = []
    seen: set = set()
    for params in combos:
        name = run_name(params, varied)
        if name in seen:
            continue
        seen.add(name)
        runs.append(Run(name, params, {k: params.get(k) for k in varied}))

    study = Study(path=path, name=str(head.get("name", path.stem)),
                  description=str(head.get("description", "")), runs=runs, varied=varied,
                  settings=settings, extra_metrics=list(head.get("metrics", [])))
    plot = data.get("plot", [])
    for spec in plot if isinstance(plot, list) else [plot]:
        if set(spec) - {"metric", "param"} or not {"metric", "param"} <= set(spec):
            raise UserInputError(f"{path}: [plot] takes metric = ... and param = ....")
        study.plots.append((spec["metric"], spec["param"]))
    return study


def check_plot(study: Study, metric: str, param: str) -> None:
    if metric not in study.metrics:
        raise UserInputError(f"Cannot plot '{metric}': the metrics are {', '.join(study.metrics)} "
                             "(add summary keys with [study] metrics = [...]).")
    names = {k for r in study.runs for k in r.params}
    if param not in names:
        raise UserInputError(f"Cannot plot against '{param}': the study's parameters are "
                             f"{', '.join(sorted(names))}.")


# --------------------------------------------------------------------------- state of runs
def adopt_renamed(study: Study, runs_dir: Path) -> int:
    """Give earlier folders of the same runs their current names.

    The hash part of a name covers every parameter value; the readable part lists the
    varied parameters, which change when the study gains a run that varies something new.
    A folder whose hash matches a run is that run, so it is renamed rather than re-run.
    Returns the number of folders renamed."""
    if not runs_dir.is_dir():
        return 0
    by_hash = {}
    for folder in runs_dir.iterdir():
        if folder.is_dir():
            by_hash.setdefault(folder.name.rsplit("-", 1)[-1], []).append(folder)
    renamed = 0
    for run in study.runs:
        target = runs_dir / run.name
        if target.exists():
            continue
        for folder in by_hash.get(run.name.rsplit("-", 1)[-1], []):
            if folder.exists() and folder != target:
                folder.rename(target)
                record = jobs.read_record(target)
                if record is not None:
                    record["run"] = run.name
                    jobs.write_json_atomic(target / jobs.JOB_FILE, record)
                renamed += 1
                break
    return renamed


def classify(study: Study, runs_dir: Path, retry_failed: bool) -> tuple[list, list, list]:
    """(to run, finished, failed and kept) for this invocation."""
    todo, finished, failed = [], [], []
    for run in study.runs:
        folder = runs_dir / run.name
        if jobs.is_finished(folder):
            finished.append(run)
            continue
        record = jobs.read_record(folder)
        if record and record.get("status") == "failed" and not retry_failed:
            failed.append(run)
        else:
            todo.append(run)
    return todo, finished, failed


def _record_failure(folder: Path, params: dict, message: str, failure: str = "refused") -> dict:
    """The record of a run that failed outside its job process (refused here, lost worker)."""
    folder.mkdir(parents=True, exist_ok=True)
    if failure == "refused":
        jobs.clear_outputs(folder)
        jobs.write_json_atomic(folder / jobs.PARAMS_FILE, {"params": params, "base_dir": None})
    record = {"run": folder.name, "params": params, "status": "failed", "failure": failure,
              "error": message, "finished": jobs.timestamp(), "metrics": {}}
    jobs.write_json_atomic(folder / jobs.JOB_FILE, record)
    return record


# --------------------------------------------------------------------------- results
def collect_rows(study: Study, runs_dir: Path) -> list[dict]:
    rows = []
    for run in study.runs:
        folder = runs_dir / run.name
        record = jobs.read_record(folder) or {"status": "pending"}
        status = record.get("status", "pending")
        if status == "running":
            status = "pending"
        row = {"run": run.name, "status": status}
        row.update(run.varied)
        metrics = record.get("metrics", {})
        summary = record.get("summary", {})
        for name in study.metrics:
            row[name] = metrics.get(name, summary.get(name))
        error = record.get("error")
        row["failure"] = record.get("failure")
        row["error"] = error.splitlines()[0][:500] if error else None
        row["folder"] = str(Path("runs") / run.name)
        rows.append(row)
    return rows


def _columns(study: Study) -> list[str]:
    return [*LEAD_COLUMNS, *study.varied, *study.metrics, *TAIL_COLUMNS]


def write_results(study: Study, out_dir: Path) -> dict:
    """results.csv (+ results.parquet with pyarrow) and failures.json; returns the paths."""
    rows = collect_rows(study, out_dir / "runs")
    columns = _columns(study)
    paths = {}
    csv_path = out_dir / "results.csv"
    tmp = csv_path.with_name("results.csv.tmp")
    with tmp.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: ("" if row.get(k) is None else _cell(row[k])) for k in columns})
    tmp.replace(csv_path)
    paths["csv"] = csv_path
    parquet = _write_parquet(rows, columns, out_dir / "results.parquet")
    if parquet:
        paths["parquet"] = parquet
    params = {r.name: r.params for r in study.runs}
    failures = [{"run": r["run"], "params": params[r["run"]], "failure": r["failure"],
                 "error": (jobs.read_record(out_dir / r["folder"]) or {}).get("error")}
                for r in rows if r["status"] == "failed"]
    jobs.write_json_atomic(out_dir / "failures.json", failures)
    paths["failures"] = out_dir / "failures.json"
    return paths


def _cell(value):
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return value


def _write_parquet(rows: list[dict], columns: list[str], path: Path) -> Path | None:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    data = {}
    for col in columns:
        values = [row.get(col) for row in rows]
        present = [v for v in values if v is not None]
        if present and all(isinstance(v, bool) for v in present):
            data[col] = pa.array(values, type=pa.bool_())
        elif present and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
            data[col] = pa.array([None if v is None else float(v) for v in values], type=pa.float64())
        else:
            data[col] = pa.array([None if v is None else str(_cell(v)) for v in values],
                                 type=pa.string())
    pq.write_table(pa.table(data), path)
    return path


def plot_metric(rows: list[dict], metric: str, param: str, varied: list[str], path: Path) -> Path:
    """``metric`` against ``param`` over the finished runs, one line per combination of the
    other varied parameters. Uses matplotlib's Agg canvas (no display, no global backend)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    done = [r for r in rows if r["status"] == "done" and isinstance(r.get(metric), (int, float))
            and r.get(param) is not None]
    missing = len(rows) - len(done)
    others = [v for v in varied if v != param]
    groups: dict[tuple, list] = {}
    for r in done:
        groups.setdefault(tuple(r.get(k) for k in others), []).append(r)
    xs_all = [r[param] for r in done]
    numeric = all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in xs_all)
    categories = list(dict.fromkeys(_value_text(x) for x in xs_all)) if not numeric else []
    fig = Figure(figsize=(6.4, 4.4), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for key, members in groups.items():
        members.sort(key=lambda r: r[param] if numeric else categories.index(_value_text(r[param])))
        x = [m[param] if numeric else categories.index(_value_text(m[param])) for m in members]
        y = [m[metric] for m in members]
        label = ", ".join(f"{k}={_value_text(v)}" for k, v in zip(others, key)) or None
        ax.plot(x, y, marker="o", label=label)
    if categories:
        ax.set_xticks(range(len(categories)), categories)
    ax.set_xlabel(param)
    ax.set_ylabel(metric)
    title = f"{metric} vs {param}"
    if missing:
        title += f" ({missing} run(s) without a value left out)"
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if others and 1 < len(groups) <= 12:
        ax.legend(fontsize=7)
    if not done:
        ax.text(0.5, 0.5, "no finished run has this metric", ha="center", va="center",
                transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(path)
    return path


# --------------------------------------------------------------------------- running
def default_workers(n_runs: int) -> int:
    """One worker per core, fewer when memory is short (about 1.5 GiB per Taichi process)."""
    from taichi_mex.sim.simulation import available_memory_bytes

    by_memory = int(available_memory_bytes() / (1.5 * 2**30))
    return max(1, min(jobs.available_cores(), max(n_runs, 1), max(by_memory, 1)))


def slots_by_host(client) -> dict:
    """Task slots (worker threads) per host of a running cluster."""
    slots: dict = {}
    try:
        info = client.scheduler_info(n_workers=-1)
    except TypeError:  # older distributed
        info = client.scheduler_info()
    for worker in info.get("workers", {}).values():
        host = worker.get("host")
        slots[host] = slots.get(host, 0) + int(worker.get("nthreads", 1))
    return slots


@dataclass
class Outcome:
    total: int
    ran: int = 0
    done: int = 0
    failed: int = 0
    skipped_finished: int = 0
    skipped_failed: int = 0
    refused_before_start: int = 0
    interrupted: bool = False
    wall_time_s: float = 0.0
    paths: dict = field(default_factory=dict)
    #: this sweep's mark in the params.json of each run it starts
    batch: str = field(default_factory=lambda: uuid.uuid4().hex[:8])


def execute(study: Study, out_dir, *, scheduler: str | None = None, workers: int | None = None,
            threads_per_run: int | None = None, timeout_s: float | None = None,
            retry_failed: bool = False, progress: bool = True, echo=print) -> Outcome:
    """Run the study's unfinished runs and write the results table; see the module doc."""
    t0 = time.perf_counter()
    out_dir = Path(out_dir).resolve()
    runs_dir = out_dir / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    _write_index(study, out_dir)
    adopt_renamed(study, runs_dir)
    todo, finished, kept_failed = classify(study, runs_dir, retry_failed)
    outcome = Outcome(total=len(study.runs), skipped_finished=len(finished),
                      skipped_failed=len(kept_failed))
    runnable = []
    for run in todo:
        try:
            jobs.resolve(run.params, study.base_dir)
        except UserInputError as exc:
            _record_failure(runs_dir / run.name, run.params, str(exc))
            outcome.refused_before_start += 1
            echo(f"refused {run.name}: {exc}")
            continue
        runnable.append(run)
    if finished or kept_failed:
        echo(f"resuming: {len(finished)} run(s) finished earlier are kept"
             + (f", {len(kept_failed)} failed run(s) kept (--retry-failed runs them again)"
                if kept_failed else ""))
    try:
        if runnable:
            _run_on_dask(study, runnable, runs_dir, outcome, scheduler=scheduler, workers=workers,
                         threads_per_run=threads_per_run, timeout_s=timeout_s, progress=progress,
                         echo=echo)
            if outcome.interrupted:
                _await_records(runnable, runs_dir, outcome.batch, echo)
    finally:  # whatever happened, the table shows every run as it stands
        outcome.paths = write_results(study, out_dir)
    rows = collect_rows(study, runs_dir)
    outcome.done = sum(r["status"] == "done" for r in rows)
    outcome.failed = sum(r["status"] == "failed" for r in rows)
    for metric, param in study.plots:
        name = re.sub(r"[^A-Za-z0-9._-]", "_", f"plot_{metric}_vs_{param}.png")
        outcome.paths[f"plot {metric}:{param}"] = plot_metric(rows, metric, param, study.varied,
                                                             out_dir / name)
    from taichi_mex.post.report import write_index

    outcome.paths["index"] = write_index(
        out_dir, f"sweep: {study.name}", outcome.paths["csv"],
        [v for k, v in outcome.paths.items() if k.startswith("plot ")])
    outcome.wall_time_s = time.perf_counter() - t0
    return outcome


def _await_records(runs, runs_dir: Path, batch: str, echo=print,
                   grace_s: float = jobs.STOP_GRACE_S) -> None:
    """After Ctrl-C: wait until every run this sweep started (its params.json names the batch)
    has a final record, so that the table shows the runs the interruption stopped as
    interrupted. Their job processes write it after their step, possibly after the Dask
    cluster is closed; one still importing when Ctrl-C came (started with Ctrl-C ignored, as
    the workers are) stops when its parent watch sees the worker gone, seconds later. Under
    load the table twice showed such a run as pending, its record as interrupted. A run with
    no final record after the grace is recorded as interrupted here."""
    def unfinished():
        out = []
        for r in runs:
            spec = jobs.read_json(runs_dir / r.name / jobs.PARAMS_FILE) or {}
            record = jobs.read_record(runs_dir / r.name) or {"status": "running"}
            if spec.get("batch") == batch and record.get("status") == "running":
                out.append(r)
        return out

    deadline = time.monotonic() + grace_s
    waiting = unfinished()
    if waiting:
        echo(f"waiting up to {grace_s:.0f} s for {len(waiting)} interrupted run(s) to stop")
    while waiting and time.monotonic() < deadline:
        time.sleep(0.2)
        waiting = unfinished()
    for r in waiting:
        record = jobs.read_record(runs_dir / r.name) or {"run": r.name, "params": r.params}
        record.update(status="interrupted", failure="interrupted",
                      error="interrupted; its job process wrote no record within "
                            f"{grace_s:.0f} s")
        jobs.write_json_atomic(runs_dir / r.name / jobs.JOB_FILE, record)


def _write_index(study: Study, out_dir: Path) -> None:
    (out_dir / "study.toml").write_text(study.path.read_text())
    jobs.write_json_atomic(out_dir / "runs.json", {
        "study": str(study.path.resolve()), "name": study.name, "varied": study.varied,
        "runs": [{"run": r.name, "params": r.params} for r in study.runs]})


def _run_on_dask(study, runnable, runs_dir, outcome, *, scheduler, workers, threads_per_run,
                 timeout_s, progress, echo) -> None:
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise UserInputError("Sweeps run on Dask: pip install distributed") from None
    from tqdm import tqdm

    cluster = None
    if scheduler:
        if scheduler.endswith(".json") and Path(scheduler).is_file():  # dask scheduler --scheduler-file
            client = Client(scheduler_file=scheduler, timeout="60s", set_as_default=False)
        else:
            client = Client(scheduler, timeout="60s", set_as_default=False)
        echo(f"submitting {len(runnable)} run(s) to the Dask cluster at {scheduler}")
    else:
        n = workers or default_workers(len(runnable))
        with _children_ignore_sigint():
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.CRITICAL)
        client = Client(cluster, set_as_default=False)
        share = threads_per_run or max(1, jobs.available_cores() // n)
        echo(f"running {len(runnable)} run(s) on a local Dask cluster of {n} worker(s), "
             f"{share} CPU thread(s) per run")
    futures: dict = {}
    failed = outcome.refused_before_start + outcome.skipped_failed
    bar = tqdm(total=outcome.total, initial=outcome.skipped_finished + failed, unit="run",
               desc=f"sweep {study.name}", disable=not progress, dynamic_ncols=True)
    try:
        slots = slots_by_host(client)
        batch = outcome.batch
        for run in runnable:
            params = dict(run.params)
            if threads_per_run and "cpu_threads" not in params:
                params["cpu_threads"] = int(threads_per_run)
            fut = client.submit(jobs.run_job_isolated, params, str(runs_dir / run.name),
                                base_dir=str(study.base_dir), timeout_s=timeout_s,
                                slots_by_host=slots, batch=batch,
                                key=f"taichi-mex-{run.name}-{batch}",
                                pure=False, retries=0)
            futures[fut] = run
        bar.set_postfix(failed=failed, refresh=False)
        for fut in as_completed(list(futures), loop=client.loop):
            run = futures[fut]
            try:
                record = fut.result()
            except Exception as exc:  # noqa: BLE001 - a lost worker costs this run only
                record = _record_failure(runs_dir / run.name, run.params,
                                         f"{type(exc).__name__}: {exc}", "worker")
            outcome.ran += 1
            if record.get("status") == "failed":
                failed += 1
                message = (record.get("error") or "").splitlines()[:1]
                bar.write(f"failed {run.name} ({record.get('failure')}): "
                          f"{message[0][:300] if message else ''}")
            bar.update(1)
            bar.set_postfix(failed=failed, refresh=False)
    except KeyboardInterrupt:
        outcome.interrupted = True
        bar.write("interrupted: cancelling the runs not finished; finished runs stay as they are")
        _cancel(client, list(futures))
    finally:
        bar.close()
        _close(client, cluster)


@contextlib.contextmanager
def _children_ignore_sigint():
    """Start the worker processes with Ctrl-C ignored: the sweep itself cancels and closes
    them, while each job process (which takes Ctrl-C back) stops its simulation cleanly."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _cancel(client, futures) -> None:
    try:
        client.cancel(futures, force=True)
    except (KeyboardInterrupt, Exception):  # noqa: BLE001 - shutting down anyway
        pass


def _close(client, cluster) -> None:
    for thing in (client, cluster):
        if thing is None:
            continue
        try:
            thing.close()
        except (KeyboardInterrupt, Exception):  # noqa: BLE001 - shutting down anyway
            pass


# --------------------------------------------------------------------------- command line
def sweep_parser() -> argparse.ArgumentParser:
    p = Parser(prog="python -m taichi_mex sweep",
                description="Run a parameter study (a TOML study file) on Dask: a local cluster "
                "sized to this machine, or an existing cluster with --scheduler. Re-running the "
                "same command resumes: finished runs are skipped.")
    p.add_argument("study", nargs="?", type=Path, help="study file (TOML), see examples/study_*.toml")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: STUDY_sweep)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="submit to this Dask scheduler (tcp://host:8786, or the JSON file of "
                        "'dask scheduler --scheduler-file') instead of starting a local cluster")
    p.add_argument("--workers", type=int, default=None,
                   help="local cluster: concurrent runs (default: cores, fewer if memory is short)")
    p.add_argument("--threads-per-run", type=int, default=None,
                   help="CPU threads per run (default: the host's cores / concurrent runs)")
    p.add_argument("--timeout", type=float, default=None, metavar="S",
                   help="stop a run after S seconds of wall time and record it as failed")
    p.add_argument("--retry-failed", action="store_true", help="run failed runs again")
    p.add_argument("--plot", action="append", default=[], metavar="METRIC:PARAM",
                   help="plot a metric against a parameter (repeatable; adds to [plot])")
    p.add_argument("--dry-run", action="store_true",
                   help="list the runs and their state; run nothing")
    p.add_argument("--list-params", action="store_true", help="list the parameter names and exit")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--arch", choices=["cpu", "gpu"], default=None,
                   help="run every run on this architecture (overrides the study's arch; not "
                        "part of the run names, so finished runs are not redone)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = sweep_parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    if args.list_params:
        print(jobs.describe_parameters())
        print("\nmetrics (results table columns):")
        for name, text in jobs.METRICS.items():
            print(f"  {name:24s} {text}")
        return 0
    if args.study is None:
        raise UserInputError("Give a study file: python -m taichi_mex sweep STUDY.toml --out DIR "
                             "(examples/study_tiny.toml is one).")
    study = load_study(args.study)
    if args.arch is not None:
        for run in study.runs:
            run.params["arch"] = args.arch
    for spec in args.plot:
        metric, sep, param = spec.partition(":")
        if not sep or not metric or not param:
            raise UserInputError(f"--plot takes METRIC:PARAM, e.g. bead_width_mm:feed_rate_factor, "
                                 f"not '{spec}'.")
        study.plots.append((metric, param))
    for metric, param in study.plots:
        check_plot(study, metric, param)
    settings = study.settings
    workers = args.workers or settings.get("workers")
    threads = args.threads_per_run or settings.get("threads_per_run")
    timeout = args.timeout or settings.get("timeout_s")
    for name, value in (("workers", workers), ("threads per run", threads), ("timeout", timeout)):
        if value is not None and not (isinstance(value, (int, float)) and value > 0):
            raise UserInputError(f"{name} must be positive, got {value!r}.")
    out = args.out or Path(f"{args.study.stem}_sweep")
    if args.dry_run:
        return _dry_run(study, out, args.retry_failed)
    outcome = execute(study, out, scheduler=args.scheduler, workers=workers,
                      threads_per_run=threads, timeout_s=timeout, retry_failed=args.retry_failed,
                      progress=not args.quiet)
    _report(outcome, out)
    if outcome.interrupted:
        return 130
    return 1 if outcome.failed else 0


def _dry_run(study: Study, out: Path, retry_failed: bool) -> int:
    runs_dir = Path(out) / "runs"
    todo, finished, failed = classify(study, runs_dir, retry_failed)
    state = {r.name: "finished" for r in finished}
    state.update({r.name: "failed (kept)" for r in failed})
    print(f"study {study.name}: {len(study.runs)} run(s), varying {', '.join(study.varied) or 'nothing'}")
    for run in study.runs:
        what = state.get(run.name)
        if what is None:
            try:
                jobs.resolve(run.params, study.base_dir)
                what = "to run"
            except UserInputError as exc:
                what = f"would be refused: {exc}"
        print(f"  {run.name:60s} {what}")
    print(f"{len(todo)} to run, {len(finished)} finished, {len(failed)} failed and kept")
    return 0


def _report(outcome: Outcome, out: Path) -> None:
    head = "interrupted" if outcome.interrupted else "done"
    print(f"{head}: {outcome.total} run(s): {outcome.done} finished, {outcome.failed} failed "
          f"({outcome.ran} run now, {outcome.skipped_finished} finished earlier, "
          f"{outcome.refused_before_start} refused before starting) in {outcome.wall_time_s:.1f} s")
    for what, path in outcome.paths.items():
        print(f"  {what:10s} {path}")
    if outcome.failed:
        print(f"failed runs and their messages: {Path(out) / 'failures.json'}; re-run with "
              "--retry-failed to try them again")
