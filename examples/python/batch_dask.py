"""Register and plan a folder of parts on a Dask cluster.

    python examples/python/batch_dask.py PARTS [--out plans] [--workers 2] [--threads-per-worker 1]
    python examples/python/batch_dask.py PARTS --scheduler tcp://10.0.0.5:8786 --threads-per-worker 4

Without ``--scheduler`` the script starts a ``distributed.LocalCluster`` of ``--workers``
processes; with it, the same code runs on the cluster at that address (``dask scheduler`` and
``dask worker`` started elsewhere; every worker needs the trimctl package and must see PARTS
at the same path). Each worker plans one part at a time (one Dask thread per local worker) with
at most ``--threads-per-worker`` rayon threads: the script sets ``RAYON_NUM_THREADS`` in every
worker process, and starts the process's rayon pool, before any part reaches it, then checks the
pool's real size (counting its threads in /proc on Linux) and refuses to run when a worker's pool
was started earlier with another size (restart those workers).

PARTS holds one subfolder per part (hidden ones skipped); the subfolder's name names the part.
The files, as ``trimctl synth --out PARTS/NAME --seed N`` writes them:

    path.csv          the CAM template path (CAD frame; ``contour,x,y,z,u,v,w``)
    cad_points.ply    the CAD as points with outward normals (PLY or PCD with nx ny nz)
    scan.ply          the scan of the clamped part in the work-piece frame (or scan.pcd, scan.xyz)
    case.json         optional: its ``scan_from_cad_nominal`` (row-major 4 x 4) is the fixture's
                      nominal pose, where registration starts; without it, the identity (the CAM
                      data in the machine frame, as ``trimctl run`` takes it)

``--config job.toml`` sets the registration (its ``[register]`` table) and the planner (its
``max_incidence_deg``, ``[beam]``, ``[zoning]``, ``[layers]``, ``[field]``, ``[machine]``,
``[galvo]`` and ``[calibration]`` tables) for every part; its other tables are not used here.
Without it, the job.toml defaults.

Results come back to this process, which writes, per part, ``OUT/NAME/``:

    plan.json           the Job (docs/DESIGN.md contract), as ``trimctl plan`` writes it
    registered.csv      the registered path
    registration.json   the per-contour quality report
    error.txt           instead, when the part failed: the stage and the error

and ``OUT/summary.json`` (every part's status, worker, rayon threads and timings). Progress is
printed as parts complete, in the order they complete. A part fails when its files cannot be
read, registration or planning raises, registration flags a contour untrustworthy (``trimctl
run`` refuses those too; registration.json is written for inspection) or the plan does not
validate (plan.json is written for inspection); the other parts go on.

Exit codes: 0 every part planned; 1 a part failed (the others' results are written) or the
arguments or the cluster were refused.

Needs ``dask`` and ``distributed`` (``scripts/python-env`` installs them) and the trimctl
package (``pip install ./crates/pybind``).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import tempfile
import time
import tomllib
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

import trimctl

SCAN_FILES = ("scan.ply", "scan.pcd", "scan.xyz")
CAD_FILE = "cad_points.ply"
PATH_FILE = "path.csv"
CASE_FILE = "case.json"
# The job.toml keys the planner takes (trim_plan::planner::PlanSettings).
PLAN_KEYS = ("max_incidence_deg", "beam", "zoning", "layers", "field", "machine", "galvo", "calibration")
# The files a part's output folder can hold, removed before a part's new results are written so
# that no stale result of an earlier run survives beside them.
OUTPUT_FILES = ("plan.json", "registered.csv", "registration.json", "error.txt")
# The thread name of trimctl's detached native calls (crates/pybind/src/gil.rs); the rayon pool
# threads they start inherit it (Linux copies a new thread's name from the thread that made it).
NATIVE_THREAD_NAME = "trimctl-worker"
PLUGIN_NAME = "trimctl-rayon-threads"


# ---- on the workers -------------------------------------------------------------------------


def rayon_pool_threads() -> Optional[int]:
    """The threads of this process's rayon pool (0: not started yet), counted in /proc; ``None``
    where /proc/self/task is not there (not Linux). A detached native call's own thread ends
    just after its result is back, so the count is read until two reads agree; a call still in
    flight in another thread would be counted too (the plugin counts before any part runs)."""
    tasks = pathlib.Path("/proc/self/task")
    if not tasks.is_dir():
        return None

    def count() -> int:
        n = 0
        for task in tasks.iterdir():
            try:
                n += (task / "comm").read_text().strip() == NATIVE_THREAD_NAME
            except OSError:  # the thread ended while we looked
                pass
        return n

    last = count()
    for _ in range(50):
        time.sleep(0.01)
        now = count()
        if now == last:
            return now
        last = now
    return last


def start_rayon_pool() -> None:
    """One small native call that runs on rayon: starts the global pool (at the size that
    ``RAYON_NUM_THREADS`` says at this moment) if it is not started yet."""
    i, j = np.meshgrid(np.arange(8.0), np.arange(8.0), indexing="ij")
    grid = np.column_stack([i.ravel(), j.ravel(), 0.1 * i.ravel() * j.ravel()])
    trimctl.estimate_normals(grid, k=6)


try:
    from distributed.diagnostics.plugin import WorkerPlugin
except ImportError:  # main() says what is missing
    WorkerPlugin = object  # type: ignore[assignment,misc]


class RayonThreadCap(WorkerPlugin):
    """Caps rayon's threads in each worker process: sets ``RAYON_NUM_THREADS`` and starts the
    pool before any part runs there (rayon reads the variable once, when its global pool
    starts). Runs on every worker there is and every worker that joins later. The pool's size as
    found afterward is kept on the worker (``trimctl_rayon_threads``) for the client to check."""

    name = PLUGIN_NAME

    def __init__(self, threads: int) -> None:
        self.threads = threads

    def setup(self, worker: Any) -> None:
        if rayon_pool_threads() in (0, None):
            os.environ["RAYON_NUM_THREADS"] = str(self.threads)
        start_rayon_pool()
        worker.trimctl_rayon_threads = rayon_pool_threads()


def worker_rayon_threads(dask_worker: Any) -> Tuple[Optional[int], Optional[str], int]:
    """What a worker's pool holds, its RAYON_NUM_THREADS and its pid (run by ``client.run``)."""
    return (
        getattr(dask_worker, "trimctl_rayon_threads", None),
        os.environ.get("RAYON_NUM_THREADS"),
        os.getpid(),
    )


class PartFailed(Exception):
    """A part's stage failed; the message names the stage and the cause."""


def plan_part(part_dir: str, register_settings: Dict[str, Any], plan_settings: Dict[str, Any]) -> Dict[str, Any]:
    """Reads one part's files, registers its path onto its scan and plans it. Runs on a worker;
    returns plain data (the Job as JSON text, the report, the registered path as CSV text)."""
    from distributed import get_worker

    folder = pathlib.Path(part_dir)
    timings: Dict[str, float] = {}
    stage = "read"
    try:
        t = time.perf_counter()
        scan_file = next((folder / f for f in SCAN_FILES if (folder / f).is_file()), None)
        if scan_file is None:
            raise FileNotFoundError(f"{folder}: no scan ({', '.join(SCAN_FILES)})")
        for name in (CAD_FILE, PATH_FILE):
            if not (folder / name).is_file():
                raise FileNotFoundError(f"{folder / name}: not there")
        scan, _ = trimctl.read_points(scan_file)
        cad, cad_normals = trimctl.read_points(folder / CAD_FILE)
        if cad_normals is None:
            raise ValueError(f"{folder / CAD_FILE}: the CAD points need outward normals (nx ny nz)")
        path = trimctl.read_path(folder / PATH_FILE)
        init = nominal_pose(folder / CASE_FILE)
        timings["read_s"] = time.perf_counter() - t

        stage = "register"
        t = time.perf_counter()
        reg = trimctl.register_path(cad, scan, path, cad_normals=cad_normals, init=init, settings=register_settings)
        timings["register_s"] = time.perf_counter() - t

        stage = "plan"
        job = None
        if not reg.untrustworthy:
            t = time.perf_counter()
            job = trimctl.plan(reg.path, settings=plan_settings).job
            timings["plan_s"] = time.perf_counter() - t
    except Exception as e:
        raise PartFailed(f"{stage}: {type(e).__name__}: {e}") from None

    # The registered path as the native writer writes it (every f64 round-trips); rebuilding a
    # Path from its arrays on the client would re-normalise the feature vectors (1 ulp off).
    with tempfile.TemporaryDirectory(prefix="trimctl-batch-") as tmp:
        csv = pathlib.Path(tmp) / "registered.csv"
        trimctl.write_path(csv, reg.path)
        registered_csv = csv.read_text()
    worker = get_worker()
    return {
        "job": None if job is None else json.dumps(job),
        "report": reg.report,
        "registered_csv": registered_csv,
        "untrustworthy": reg.untrustworthy,
        "timings_s": timings,
        "worker": worker.address,
        "pid": os.getpid(),
        "rayon_threads": getattr(worker, "trimctl_rayon_threads", None),
    }


def nominal_pose(case_file: pathlib.Path) -> np.ndarray:
    """The fixture's nominal ``scan_from_cad`` from case.json, else the identity."""
    if not case_file.is_file():
        return np.eye(4)
    try:
        m = np.asarray(json.loads(case_file.read_text())["scan_from_cad_nominal"], dtype=np.float64)
    except (KeyError, ValueError, TypeError) as e:
        raise ValueError(f"{case_file}: scan_from_cad_nominal: {e}") from None
    if m.shape != (4, 4):
        raise ValueError(f"{case_file}: scan_from_cad_nominal: expected 4 x 4, got {m.shape}")
    return m


# ---- on the client --------------------------------------------------------------------------


def find_parts(folder: pathlib.Path) -> List[pathlib.Path]:
    if not folder.is_dir():
        raise SystemExit(f"batch_dask: {folder}: not a folder")
    parts = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not parts:
        raise SystemExit(f"batch_dask: {folder}: no part subfolders (see --help for the layout)")
    return parts


def load_config(file: Optional[pathlib.Path]) -> Tuple[Dict[str, Any], Dict[str, Any]]:
    """(register settings, plan settings) from a job.toml."""
    if file is None:
        return {}, {}
    try:
        config = tomllib.loads(file.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise SystemExit(f"batch_dask: --config {file}: {e}") from None
    register = dict(config.get("register", {}))
    plan = {k: config[k] for k in PLAN_KEYS if k in config}
    unused = sorted(set(config) - set(PLAN_KEYS) - {"register"})
    if unused:
        print(f"batch_dask: --config {file}: not used by registration or planning: {', '.join(unused)}",
              file=sys.stderr)
    return register, plan


def start_client(args: argparse.Namespace):
    """A client of the cluster at --scheduler, or of a new LocalCluster of --workers processes."""
    from distributed import Client, LocalCluster

    if args.scheduler:
        try:
            client = Client(args.scheduler, timeout=args.connect_timeout_s)
        except (OSError, TimeoutError, ValueError) as e:
            raise SystemExit(f"batch_dask: --scheduler {args.scheduler}: cannot connect: {e}") from None
        try:
            client.wait_for_workers(1, timeout=args.connect_timeout_s)
        except TimeoutError:
            client.close()
            raise SystemExit(f"batch_dask: --scheduler {args.scheduler}: no worker within "
                             f"{args.connect_timeout_s:g} s") from None
        return client, None
    cluster = LocalCluster(
        n_workers=args.workers,
        threads_per_worker=1,  # one part at a time per process; rayon has the cores
        processes=True,
        dashboard_address=None,
    )
    return Client(cluster), cluster


def cap_rayon_threads(client: Any, threads: int) -> Dict[str, Any]:
    """Registers the cap on every worker and checks what each pool holds. Returns the per-worker
    figures; raises SystemExit naming the workers whose pool is another size."""
    client.register_plugin(RayonThreadCap(threads), name=PLUGIN_NAME)
    seen = client.run(worker_rayon_threads)
    wrong = {w: n for w, (n, _, _) in seen.items() if n is not None and n != threads}
    if wrong:
        raise SystemExit(
            "batch_dask: rayon pools already started with another size on "
            + ", ".join(f"{w} ({n} threads)" for w, n in sorted(wrong.items()))
            + f"; rayon reads RAYON_NUM_THREADS once per process: restart those workers (or start "
            f"them with RAYON_NUM_THREADS={threads})"
        )
    return {w: {"rayon_threads": n, "RAYON_NUM_THREADS": env, "pid": pid} for w, (n, env, pid) in seen.items()}


def write_result(out: pathlib.Path, result: Dict[str, Any]) -> Optional[str]:
    """Writes a part's results into its output folder; returns what makes it a failure, if
    anything (untrustworthy contours, a plan that does not validate)."""
    (out / "registration.json").write_text(json.dumps(result["report"], indent=2))
    (out / "registered.csv").write_text(result["registered_csv"])
    if result["job"] is None:
        bad = result["untrustworthy"]
        ids = ", ".join(map(str, bad[:10])) + (", ..." if len(bad) > 10 else "")
        return (f"register: {len(bad)} of {len(result['report']['contours'])} contours "
                f"untrustworthy ({ids}; registration.json written for inspection; not planned)")
    job = json.loads(result["job"])
    (out / "plan.json").write_text(json.dumps(job, indent=2))
    if not job["validation"]["passed"]:
        return (f"plan: does not validate ({len(job['validation']['violations'])} violations; "
                f"plan.json written for inspection)")
    return None


def describe(result: Dict[str, Any]) -> str:
    t = result["timings_s"]
    text = (f"on {result['worker']} (pid {result['pid']}, rayon {result['rayon_threads']} threads): "
            f"read {t['read_s']:.2f} s, register {t['register_s']:.2f} s")
    if "plan_s" in t:
        job = json.loads(result["job"])
        layers = sum(len(z["layers"]) for z in job["zones"])
        text += (f", plan {t['plan_s']:.2f} s; {len(job['zones'])} zones, {layers} layers, "
                 f"estimate {job['estimate']['total_s']:.1f} s")
    return text


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a usage error exiting 1, as trimctl's own commands do (2 reads as a
    device fault there)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(1, f"{self.prog}: error: {message}\n")


def main(argv: Optional[List[str]] = None) -> int:
    ap = ArgumentParser(
        description=__doc__.split("\n\n")[0] if __doc__ else None,
        epilog=__doc__.split("\n\n", 2)[2] if __doc__ else None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("parts", type=pathlib.Path, help="folder of parts, one subfolder each (layout below)")
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("plans"), metavar="DIR",
                    help="output folder: OUT/NAME/ per part and OUT/summary.json (default: plans)")
    ap.add_argument("--scheduler", metavar="ADDRESS",
                    help="a running Dask scheduler (tcp://host:8786); default: a LocalCluster")
    ap.add_argument("--workers", type=int, default=None, metavar="N",
                    help="LocalCluster worker processes (default: cores / --threads-per-worker)")
    ap.add_argument("--threads-per-worker", type=int, default=1, metavar="N",
                    help="rayon threads per worker process (RAYON_NUM_THREADS; default 1)")
    ap.add_argument("--config", type=pathlib.Path, metavar="JOB_TOML", help="job.toml: [register] and the planner's tables")
    ap.add_argument("--connect-timeout-s", type=float, default=60.0, metavar="S",
                    help="how long to wait for the scheduler and a first worker (default 60)")
    args = ap.parse_args(argv)
    if args.threads_per_worker < 1:
        ap.error(f"--threads-per-worker: must be at least 1, got {args.threads_per_worker}")
    if args.scheduler and args.workers is not None:
        ap.error("--workers: only for a LocalCluster; the cluster at --scheduler has its own workers")
    if args.workers is None:
        args.workers = max(1, (os.cpu_count() or 1) // args.threads_per_worker)
    if args.workers < 1:
        ap.error(f"--workers: must be at least 1, got {args.workers}")
    try:
        from distributed import as_completed
    except ImportError:
        print("batch_dask: needs dask and distributed (scripts/python-env installs them)", file=sys.stderr)
        return 1

    parts = find_parts(args.parts)
    register_settings, plan_settings = load_config(args.config)
    t0 = time.perf_counter()
    client, cluster = start_client(args)
    try:
        workers = cap_rayon_threads(client, args.threads_per_worker)
        where = args.scheduler or f"LocalCluster of {args.workers}"
        print(f"cluster: {where}, {len(workers)} workers, rayon threads per worker: "
              f"{sorted(w['rayon_threads'] for w in workers.values())}", flush=True)

        futures = {
            client.submit(plan_part, str(part.resolve()), register_settings, plan_settings,
                          pure=False, key=f"trimctl-plan-{part.name}-{os.urandom(4).hex()}"): part.name
            for part in parts
        }
        summary: Dict[str, Any] = {}
        for done, future in enumerate(as_completed(futures), start=1):
            name = futures[future]
            out = args.out / name
            out.mkdir(parents=True, exist_ok=True)
            for stale in OUTPUT_FILES:
                (out / stale).unlink(missing_ok=True)
            try:
                result = future.result()
                problem = write_result(out, result)
                entry = {k: result[k] for k in ("worker", "pid", "rayon_threads", "timings_s", "untrustworthy")}
            except Exception as e:  # the part's own failure, or its worker's (KilledWorker)
                problem = str(e) if isinstance(e, PartFailed) else f"{type(e).__name__}: {e}"
                result, entry = None, {}
            future.release()
            if problem is None:
                summary[name] = {"status": "planned", **entry}
                print(f"[{done}/{len(parts)}] {name}: planned {describe(result)}", flush=True)
            else:
                summary[name] = {"status": "failed", "error": problem, **entry}
                (out / "error.txt").write_text(f"{name}: {problem}\n")
                print(f"[{done}/{len(parts)}] {name}: FAILED: {problem}", file=sys.stderr, flush=True)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    wall_s = time.perf_counter() - t0
    failed = sorted(n for n, s in summary.items() if s["status"] != "planned")
    (args.out / "summary.json").write_text(json.dumps({
        "parts": summary,
        "scheduler": args.scheduler,
        "workers": workers,
        "threads_per_worker": args.threads_per_worker,
        "wall_s": wall_s,
    }, indent=2))
    print(f"batch: {len(parts) - len(failed)} of {len(parts)} parts planned"
          + (f", failed: {', '.join(failed)}" if failed else "")
          + f"; wall {wall_s:.1f} s; results in {args.out}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
