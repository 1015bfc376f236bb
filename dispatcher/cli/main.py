"""agrifleet's command line: parses arguments and forwards to typed functions.

Each sub-command is one ``cmd_*`` handler; the work itself lives in planner/ and dispatcher/.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dispatcher.config.errors import DispatcherError
from dispatcher.link import wire
from dispatcher.link.keys import add_signing_arguments
from planner.errors import PlannerError

log = logging.getLogger("agrifleet")

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2


class ProgressBar:
    """A progress line on stderr (generation, best cost, elapsed) once a run passes 1 s,
    only when stderr is a terminal."""

    def __init__(self, total: int, label: str) -> None:
        self.total = total
        self.label = label
        self.enabled = sys.stderr.isatty()
        self._progress: Any = None
        self._task: Any = None
        self._started = time.perf_counter()

    def __call__(self, generation: int, best: float, elapsed: float) -> None:
        if not self.enabled or elapsed < 1.0:
            return
        if self._progress is None:
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self._progress = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                TextColumn("gen {task.completed:>5.0f}  best {task.fields[best]:.2f}"),
                TimeElapsedColumn(),
                console=Console(stderr=True),
                transient=True,
            )
            self._progress.start()
            self._task = self._progress.add_task(self.label, total=self.total, best=best)
        self._progress.update(self._task, completed=generation, best=best)

    def close(self) -> None:
        if self._progress is not None:
            self._progress.stop()


def cmd_mtsp(args: argparse.Namespace) -> int:
    from planner.solve import solve, stop_after
    from planner.tsplib import read_instance

    instance = read_instance(args.instance)
    problem = instance.to_problem(args.salesmen, args.distance)
    bar = ProgressBar(args.generations, f"{instance.name} m={args.salesmen}")
    try:
        result = solve(
            problem,
            args.objective,
            args.algorithm,
            stop_after(args.generations, args.time_limit),
            seed=args.seed,
            on_generation=bar,
        )
    finally:
        bar.close()
    routes = [[int(node) for node in route] for route in result.route_ids()]
    if args.json:
        print(
            json.dumps(
                {
                    "instance": instance.name,
                    "salesmen": args.salesmen,
                    "objective": args.objective,
                    "algorithm": args.algorithm,
                    "distance": args.distance,
                    "cost": result.cost,
                    "routes": routes,
                    "elapsed_s": round(result.elapsed_s, 3),
                }
            )
        )
        return EXIT_OK
    figs = result.figures
    print(
        f"{instance.name}: {args.salesmen} salesmen, {args.objective} by {args.algorithm}, "
        f"{args.distance} distances, seed {args.seed}"
    )
    print(
        f"cost {result.cost:.2f} (total {figs.distance_m:.2f}, longest {figs.max_distance_m:.2f})"
        f" after {result.generations} generations in {result.elapsed_s:.2f} s"
    )
    for k, (route, fig) in enumerate(zip(routes, figs.routes, strict=True), start=1):
        print(
            f"  salesman {k}: {fig.distance_m:10.2f}  {len(route):4d} nodes: "
            + " ".join(map(str, route))
        )
    return EXIT_OK


def cmd_bench_paper(args: argparse.Namespace) -> int:
    from planner.paper import bench_report

    tables = {int(t) for t in args.tables.split(",")}
    report = bench_report(
        tables,
        args.runs,
        args.time_limit,
        args.generations,
        progress=lambda line: print(line, file=sys.stderr, flush=True),
    )
    if args.out:
        Path(args.out).write_text(report)
    print(report)
    return EXIT_OK


def load_scenario_args(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """The scenario with the command line's overrides (--fields, --machines)."""
    from dispatcher.config.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    if args.fields:
        scenario = scenario.with_farm(args.fields)
    if args.machines:
        scenario = scenario.with_machines(args.machines)
    return scenario


def inputs_fingerprint(scenario, args: argparse.Namespace) -> str:  # type: ignore[no-untyped-def]
    """What a plan is made from: the scenario and farm files as they are now, the fleet
    and the options that change the plan. A stored run made from other inputs is not
    resumed by mistake."""
    import hashlib

    h = hashlib.sha256()
    for source in (scenario.source, scenario.farm.source):
        with contextlib.suppress(OSError):
            h.update(Path(source).read_bytes())
    h.update(repr(scenario.vehicles).encode())
    h.update(repr(scenario.solver).encode())
    h.update(repr((args.objective, args.time_limit, args.seed)).encode())
    return h.hexdigest()[:16]


def plan_scenario(args: argparse.Namespace, scenario=None):  # type: ignore[no-untyped-def]
    """Load the scenario with the command line's overrides (unless given) and plan it."""
    from dispatcher.mission.plan import dispatch_plan
    from planner.field_plan import plan_farm
    from planner.solve import stop_after

    scenario = scenario or load_scenario_args(args)
    solver = scenario.solver
    plan = plan_farm(
        scenario.farm,
        [v.machine for v in scenario.vehicles],
        args.objective or solver.objective,
        solver.algorithm,
        stop_after(solver.generations, args.time_limit or solver.time_limit_s),
        seed=solver.seed if args.seed is None else args.seed,
    )
    return dispatch_plan(scenario, plan)


def print_plan_table(dispatch) -> None:  # type: ignore[no-untyped-def]
    doc = dispatch.document
    print(
        f"plan {doc.plan_id} for {doc.farm_id}: objective {doc.objective}, "
        f"{len(doc.machines)} machines, {len(doc.fields)} fields"
    )
    print(
        f"{'machine':8} {'width m':>7} {'fields':>6} {'road km':>8} {'turns':>6} {'fuel L':>8} "
        f"{'time h':>7}  order"
    )
    for m in doc.machines:
        print(
            f"{m.id:8} {m.working_width_m:7.1f} {len(m.fields):6d} "
            f"{m.distance_m / 1000:8.2f} {m.turns:6.0f} {m.fuel_l:8.1f} {m.time_h:7.2f}  "
            + " ".join(m.fields)
        )
    t = doc.totals
    print(
        f"{'total':8} {'':7} {len(doc.fields):6d} {t['distance_m'] / 1000:8.2f} "
        f"{sum(m.turns for m in doc.machines):6.0f} {t['fuel_l']:8.1f} {t['time_h']:7.2f}  "
        f"makespan {t['makespan_h']:.2f} h"
    )


def cmd_plan(args: argparse.Namespace) -> int:
    from dispatcher.mission.plan import write_plan_files

    dispatch = plan_scenario(args)
    written = write_plan_files(dispatch, args.out)
    print_plan_table(dispatch)
    print(f"wrote {len(written)} files to {args.out}")
    return EXIT_OK


def cmd_serve(args: argparse.Namespace) -> int:
    from dispatcher.daemon.server import DaemonConfig, Dispatcher
    from dispatcher.daemon.store import Store, StoreError, default_data_dir
    from dispatcher.link.keys import signing_keys
    from dispatcher.tools.replan import replanner_for, replanner_resumed

    scenario = load_scenario_args(args)
    keys = signing_keys(args, scenario, [v.id for v in scenario.vehicles])
    data_dir = args.data_dir or default_data_dir(scenario.farm_id)
    fingerprint = inputs_fingerprint(scenario, args)
    store = Store.open(data_dir, scenario.farm_id, args.sync)
    try:
        if args.fresh and (abandoned := store.abandon_unfinished()) is not None:
            print(f"--fresh: run {abandoned} in {store.path} abandoned (kept there as such)")
        run = store.unfinished_run()
        if run is not None:
            if run.fingerprint != fingerprint:
                raise StoreError(
                    f"{store.path} holds unfinished run {run.id} (plan {run.job.plan_id}) "
                    f"made from other inputs: {args.scenario}, its farm or the options changed "
                    "since. Serve it with the same ones to finish it, or add --fresh to "
                    "start over"
                )
            store.resume_run(run)
            job = run.job
            replanner = replanner_resumed(scenario, job)
            print(f"resuming run {run.id} of plan {job.plan_id} from {store.path}")
        else:
            dispatch = plan_scenario(args, scenario)
            print_plan_table(dispatch)
            job = dispatch.job()
            run_id = store.begin_run(job, fingerprint)
            print(f"run {run_id} kept in {store.path}")
            replanner = replanner_for(scenario, dispatch)
        daemon = Dispatcher(
            DaemonConfig(
                job=job,
                zenoh=wire.zenoh_options(args, True),
                log_dir=args.log_dir,
                heartbeat_timeout_s=scenario.watch.lost_after_s,
                stall_after_s=scenario.watch.stall_after_s,
                lost_grace_s=scenario.watch.lost_grace_s,
                store=store,
                resume=run,
                replanner=replanner,
                keys=keys,
            )
        )
        code = daemon.run()
    finally:
        store.close()
    print(f"log: {daemon.log_path}")
    return code


def cmd_sim(args: argparse.Namespace) -> int:
    """``agrifleet sim ...`` is ``python -m sim_vehicles ...``: one set of options."""
    from sim_vehicles.__main__ import main as sim_main

    return sim_main(args.rest, prog="agrifleet sim")


def cmd_keys(args: argparse.Namespace) -> int:
    from dispatcher.config.errors import ConfigError
    from dispatcher.config.scenario import load_scenario
    from dispatcher.link.keys import key_path, write_keys

    scenario = load_scenario(args.scenario)
    folder = args.keys or scenario.keys_dir
    if folder is None:
        raise ConfigError(
            f'{args.scenario}: where to? give --keys DIR, or keys = "DIR" in the scenario'
        )
    ids = [v.id for v in scenario.vehicles]
    written = write_keys(folder, ids, replace=args.replace)
    for vid in ids:
        path = key_path(folder, vid)
        print(f"{vid}: {path}{'' if path in written else ' (kept: it had one)'}")
    print(
        f"{len(written)} new key(s) in {folder}; give each vehicle its own (docs/bridge.md: "
        "SETUP_SIGNING for ArduPilot) and keep the folder readable by the dispatcher only"
    )
    return EXIT_OK


def cmd_bridge(args: argparse.Namespace) -> int:
    from dispatcher.tools.bridge import bridge_command

    return bridge_command(args, wire.zenoh_options(args, False))


def cmd_demo(args: argparse.Namespace) -> int:
    from dispatcher.tools.demo import DEFAULT_SCENARIO, demo_faults, run_demo, summary

    args.scenario = args.scenario or DEFAULT_SCENARIO
    scenario = load_scenario_args(args)
    faults = demo_faults(  # checked before planning: a bad option costs no solver time
        [v.id for v in scenario.vehicles],
        kill=args.kill,
        stall=args.stall,
        loss=args.loss,
        duplicate=args.duplicate,
        delay_ms=args.delay,
        radio_seed=args.radio_seed,
    )
    dispatch = plan_scenario(args, scenario)
    print_plan_table(dispatch)
    result = run_demo(Path(args.scenario), dispatch, args.speedup, args.log_dir, faults=faults)
    print(summary(result.daemon, result))
    print(f"log: {result.daemon.log_path}")
    return result.code


def cmd_router(args: argparse.Namespace) -> int:
    from dispatcher.tools.router import DEFAULT_ROUTER_ENDPOINT, run_router

    if not args.listen:
        args.listen = [DEFAULT_ROUTER_ENDPOINT]
    return run_router(wire.zenoh_options(args, False))


def cmd_review(args: argparse.Namespace) -> int:
    from dispatcher.recording.mcap_file import read_logs
    from dispatcher.review.report import review_contents, review_json, review_table

    log = read_logs(args.logs)  # several files (or a directory) of one run read as one
    review = review_contents(log)
    if args.plot:
        from dispatcher.review.plot import plot_review

        plot_review(review, args.plot, title=Path(log.source).name)
    if args.json:
        print(json.dumps(review_json(review)))
    else:
        print(review_table(review))
        if args.plot:
            print(f"plot: {args.plot}")
    return EXIT_OK


def cmd_bench_peer(args: argparse.Namespace) -> int:
    """`bench mtsp` and `bench farm`: ours and a peer side by side."""
    from dispatcher.tools.bench import Runs, bench_farm, bench_mtsp, parse_cells, parse_farms

    runs = Runs(args.time_limit, args.runs, args.seed, args.algorithm)

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    if args.suite == "mtsp":
        report = bench_mtsp(parse_cells(args.cells), args.peer, args.objective, runs, progress)
    else:
        report = bench_farm(parse_farms(args.farms), args.peer, runs, progress)
    print(report)
    return EXIT_OK


def add_bench_arguments(p: argparse.ArgumentParser, time_limit: float) -> None:
    from planner.choices import ALGORITHMS, DEFAULT_ALGORITHM

    p.add_argument("--time-limit", type=float, default=time_limit, help="seconds per run")
    p.add_argument("--runs", type=int, default=5, help="our seeds per cell")
    p.add_argument("--seed", type=int, default=1, help="our first seed (and the peer's)")
    p.add_argument("--algorithm", choices=ALGORITHMS, default=DEFAULT_ALGORITHM)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="agrifleet", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", required=True)
    from planner.choices import ALGORITHMS, DEFAULT_ALGORITHM

    p = sub.add_parser("mtsp", help="solve a TSPLIB instance as a multiple-TSP")
    p.add_argument("instance", type=Path, help="TSPLIB .tsp file; node 1 is the depot")
    p.add_argument("-m", "--salesmen", type=int, required=True)
    p.add_argument("--objective", choices=["minsum", "minmax"], default="minsum")
    p.add_argument("--algorithm", choices=ALGORITHMS, default=DEFAULT_ALGORITHM)
    p.add_argument("--time-limit", type=float, default=None, help="seconds")
    p.add_argument("--generations", type=int, default=2000)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--distance", choices=["euclidean", "tsplib"], default="euclidean")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=cmd_mtsp)

    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="suite", required=True)
    p = bench_sub.add_parser("paper", help="rerun the paper's tables beside its figures")
    p.add_argument("--tables", default="2,3,4,5,8,9,10")
    p.add_argument("--runs", type=int, default=5, help="seeds per cell")
    p.add_argument("--time-limit", type=float, default=30.0, help="seconds per run")
    p.add_argument("--generations", type=int, default=2000)
    p.add_argument("--out", type=Path, default=None, help="also write the report here")
    p.set_defaults(handler=cmd_bench_paper)
    from dispatcher.tools.bench import DEFAULT_CELLS, DEFAULT_FARMS, PEERS

    p = bench_sub.add_parser("mtsp", help="ours and OR-Tools or PyVRP on TSPLIB mTSP cells")
    p.add_argument("--peer", choices=PEERS, default=None)
    p.add_argument("--cells", default=DEFAULT_CELLS, help="INSTANCE:M,… (default %(default)s)")
    p.add_argument("--objective", choices=["minsum", "minmax"], default="minsum")
    add_bench_arguments(p, 10.0)
    p.set_defaults(handler=cmd_bench_peer)
    p = bench_sub.add_parser("farm", help="ours and OR-Tools on generated farms (makespan)")
    p.add_argument("--peer", choices=["ortools"], default=None)
    p.add_argument("--farms", default=DEFAULT_FARMS, help="FIELDSxMACHINES,… (default %(default)s)")
    add_bench_arguments(p, 60.0)
    p.set_defaults(handler=cmd_bench_peer)
    p = sub.add_parser("plan", help="plan a scenario and write missions, plan.json, map.png")
    add_plan_arguments(p)
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.set_defaults(handler=cmd_plan)

    p = sub.add_parser(
        "serve",
        help="the dispatcher daemon: plan (or resume the unfinished run), upload, follow, record",
    )
    add_plan_arguments(p)
    p.add_argument("--log-dir", type=Path, default=Path("logs"))
    p.add_argument(
        "--data-dir",
        type=Path,
        help="where the dispatcher keeps its state (an SQLite database) to resume after a "
        "restart (default $XDG_STATE_HOME/agrifleet/FARM, else ~/.local/state/agrifleet/FARM)",
    )
    p.add_argument(
        "--fresh",
        action="store_true",
        help="do not resume the unfinished run of the data directory: plan again",
    )
    p.add_argument(
        "--sync",
        choices=["full", "normal"],
        default="full",
        help="SQLite synchronous mode: full survives a power cut, normal only a crash of "
        "the dispatcher (docs/restart.md)",
    )
    add_signing_arguments(p)
    wire.add_zenoh_arguments(p)
    p.set_defaults(handler=cmd_serve)

    p = sub.add_parser(
        "sim",
        help="simulated tractors speaking MAVLink over Zenoh (`agrifleet sim --help`: the "
        "options of python -m sim_vehicles)",
        add_help=False,
    )
    p.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    p.set_defaults(handler=cmd_sim)

    p = sub.add_parser("keys", help="make the vehicles' MAVLink signing keys")
    p.add_argument("scenario", type=Path, help="scenario TOML (its fleet)")
    p.add_argument(
        "--keys",
        metavar="DIR",
        help="where to write them, <vehicle id>.key each, mode 600 (default: the scenario's "
        "'keys')",
    )
    p.add_argument("--replace", action="store_true", help="new keys for vehicles that have one too")
    p.set_defaults(handler=cmd_keys)

    p = sub.add_parser("demo", help="plan, simulate the fleet and dispatch, end to end")
    p.add_argument(
        "scenario",
        type=Path,
        nargs="?",
        default=None,
        help="scenario TOML (default config/changji.toml)",
    )
    p.add_argument("--machines", type=int)
    p.add_argument(
        "--speedup",
        type=float,
        default=None,
        help="simulated seconds per second (default: fit the run into ~45 s)",
    )
    p.add_argument("--log-dir", type=Path, default=Path("logs"))
    p.add_argument("--objective", choices=["makespan", "distance", "time", "fuel", "minmax"])
    p.add_argument("--time-limit", type=float, help="solver seconds")
    p.add_argument("--seed", type=int)
    g = p.add_argument_group("fault injection (docs/demo.md)")
    g.add_argument(
        "--kill",
        action="append",
        default=[],
        metavar="VEHICLE@FRACTION",
        help="SIGKILL that tractor's simulator when the fleet has done FRACTION (0..1) of its "
        "planned work (repeatable)",
    )
    g.add_argument(
        "--stall",
        action="append",
        default=[],
        metavar="VEHICLE@FRACTION",
        help="at FRACTION of the work that tractor stops moving but keeps reporting, armed in "
        "AUTO (repeatable)",
    )
    g.add_argument(
        "--loss",
        type=float,
        default=0.0,
        metavar="P",
        help="every radio loses this share of frames",
    )
    g.add_argument(
        "--duplicate",
        type=float,
        default=0.0,
        metavar="P",
        help="every radio sends this share of frames twice",
    )
    g.add_argument(
        "--delay", type=float, default=0.0, metavar="MS", help="frames arrive 0 to MS ms late"
    )
    g.add_argument("--radio-seed", type=int, default=1, metavar="N", help="the radios' seed")
    p.set_defaults(handler=cmd_demo, fields=None)

    from dispatcher.tools.bridge import add_bridge_arguments

    p = sub.add_parser("bridge", help="connect one real MAVLink autopilot to the dispatcher")
    add_bridge_arguments(p)
    wire.add_zenoh_arguments(p)
    p.set_defaults(handler=cmd_bridge)

    p = sub.add_parser("review", help="what happened in a run: table, JSON, map and Gantt chart")
    p.add_argument(
        "logs",
        type=Path,
        nargs="+",
        metavar="LOG",
        help="MCAP logs written by the dispatcher, or a directory of them: one run, "
        "read as one in order of start time",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", type=Path, help="write a map and Gantt chart PNG here")
    p.set_defaults(handler=cmd_review)

    p = sub.add_parser("router", help="a Zenoh router (for several gateways or farms)")
    wire.add_zenoh_arguments(p, mode="router")
    p.set_defaults(handler=cmd_router)
    return parser


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", type=Path, help="scenario TOML (see config/README.md)")
    p.add_argument("--fields", type=Path, help="farm GeoJSON replacing the scenario's")
    p.add_argument("--machines", type=int, help="use the first K machines of the fleet")
    p.add_argument("--objective", choices=["makespan", "distance", "time", "fuel", "minmax"])
    p.add_argument("--time-limit", type=float, help="solver seconds")
    p.add_argument("--seed", type=int)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # Daemons log what they do; interactive commands keep the terminal for their own output.
    quiet = args.command in ("demo", "plan", "mtsp", "bench", "review")
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else (logging.WARNING if quiet else logging.INFO),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(args.handler(args))
    except (PlannerError, DispatcherError) as exc:
        print(f"agrifleet: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        # Output piped into `head` and the like: stop quietly, as Unix tools do.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except KeyboardInterrupt:
        print("agrifleet: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
