"""agrifleet plans the work of a fleet of autonomous tractors on a farm's fields and
dispatches it to them over Zenoh as MAVLink missions, recording everything to MCAP.

Start with `agrifleet demo`; plan your own farm with `agrifleet plan SCENARIO.toml --out DIR`
(scenario, fleet and farm files: config/README.md).
"""

# The command line parses arguments and forwards to typed functions: each sub-command is
# one ``cmd_*`` handler; the work itself lives in planner/, dispatcher/ and agrifleet/.

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dispatcher.config.errors import ConfigError, DispatcherError
from dispatcher.link import wire
from dispatcher.link.keys import add_signing_arguments
from dispatcher.link.signals import sigterm_interrupts
from planner.choices import SLACK_SHARE
from planner.errors import PlannerError

log = logging.getLogger("agrifleet")

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2
EXIT_INCOMPLETE = 3  # dispatcher.daemon.server's (tests/test_cli.py checks they agree)
EXIT_LINK_DOWN = 4  # sim_vehicles' --mavlink socket
EXIT_STATE_UNWRITTEN = 5  # the data directory refused a write (dispatcher.daemon.store)
EXIT_INTERRUPTED = 130
EXIT_CODES = {
    EXIT_OK: "done (serve, demo: every field done; sim, bridge, router: stopped by Ctrl-C or "
    "SIGTERM)",
    EXIT_FAILURE: "an unexpected error (a bug: please report it with the traceback)",
    EXIT_BAD_INPUT: "bad input: a file, key or option, named in the message; no plan, mission "
    "or run written (serve: the data and log directories may have been made)",
    EXIT_INCOMPLETE: "serve, demo: the run ended with fields not done (vehicles failed or lost)",
    EXIT_LINK_DOWN: "sim --mavlink: the MAVLink socket could not be opened",
    EXIT_STATE_UNWRITTEN: "serve, demo: the dispatcher's state could not be written (a full "
    "disk, a read-only data directory); what was kept before is intact: free space and serve "
    "again to resume",
    EXIT_INTERRUPTED: "serve, demo, plan, bench: interrupted (Ctrl-C, SIGTERM); a run's log is "
    "finished first",
}
"""What the exit codes mean, in `agrifleet --help` and the README."""


class ProgressBar:
    """The solver's progress on stderr, only when stderr is a terminal: generations and best
    cost against its limits (``generations``, ``time_limit_s``).

    With ``waiting`` (what happens before the first generation: coverage, compiling), it
    shows at once; without, once the run passes 1 s."""

    def __init__(
        self,
        total: int,
        label: str,
        time_limit_s: float | None = None,
        waiting: str | None = None,
    ) -> None:
        self.total = total
        self.label = label
        self.time_limit_s = time_limit_s
        self.enabled = sys.stderr.isatty()
        self._progress: Any = None
        self._task: Any = None
        self._solving = False
        if waiting is not None and self.enabled:
            self._start(waiting, None)

    def _start(self, description: str, total: int | None) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        self._progress = Progress(
            SpinnerColumn(),
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.fields[detail]}"),
            TimeElapsedColumn(),
            console=Console(stderr=True),
            transient=True,
        )
        self._progress.start()
        self._task = self._progress.add_task(description, total=total, detail="")

    def __call__(self, generation: int, best: float, elapsed: float) -> None:
        if not self.enabled or (self._progress is None and elapsed < 1.0):
            return
        if self._progress is None:
            self._start(self.label, self.total)
        if not self._solving:
            self._solving = True
            self._progress.update(self._task, description=self.label, total=self.total)
        done = float(generation)
        if self.time_limit_s:  # whichever limit comes first
            done = max(done, self.total * min(elapsed / self.time_limit_s, 1.0))
        self._progress.update(
            self._task, completed=done, detail=f"gen {generation:>5d}  best {best:.2f}"
        )

    def close(self) -> None:
        if self._progress is not None:
            self._progress.stop()


def compile_solver():  # type: ignore[no-untyped-def]
    """Make the solver's kernels ready: load them from numba's cache, or compile them (the
    first run after installing) saying so on stderr, with the seconds it took."""
    from planner.kernels import COMPILE_ESTIMATE_S, compile_kernels

    def say() -> None:
        print(
            f"compiling the solver's kernels once for this install (~{COMPILE_ESTIMATE_S} s)…",
            file=sys.stderr,
            flush=True,
        )

    done = compile_kernels(say)
    if done.cold:
        print(
            f"compiled in {done.seconds:.1f} s; cached for the next runs",
            file=sys.stderr,
            flush=True,
        )
    return done


def cmd_warm(args: argparse.Namespace) -> int:
    done = compile_solver()
    if done.cache_dir is None:
        print("nothing to compile: numba's JIT is off (NUMBA_DISABLE_JIT)")
    elif done.cold:
        print(f"the solver's kernels are compiled and cached in {done.cache_dir}")
    else:
        print(
            f"the solver's kernels were compiled already: loaded from {done.cache_dir} "
            f"in {done.seconds:.1f} s"
        )
    return EXIT_OK


def cmd_mtsp(args: argparse.Namespace) -> int:
    from planner.solve import solve, stop_after
    from planner.tsplib import read_instance

    instance = read_instance(args.instance)
    problem = instance.to_problem(args.salesmen, args.distance)
    compile_solver()
    bar = ProgressBar(args.generations, f"{instance.name} m={args.salesmen}", args.time_limit)
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
        algorithm=args.algorithm,
    )
    if args.out:
        Path(args.out).write_text(report)
    print(report)
    return EXIT_OK


def load_scenario_args(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """The scenario with the command line's overrides (--fields, --machines, --objective,
    --finish-within), each checked as in the file."""
    from agrifleet.api import scenario_for

    scenario = scenario_for(
        args.scenario,
        args.fields,
        args.machines,
        id_field=getattr(args, "id_field", None),
        name_field=getattr(args, "name_field", None),
    )
    if getattr(args, "objective", None) is not None:
        scenario = scenario.with_objective(args.objective)
    if getattr(args, "finish_within", None) is not None:
        scenario = scenario.with_deadline(args.finish_within)
    return scenario


def inputs_fingerprint(  # type: ignore[no-untyped-def]
    scenario, args: argparse.Namespace, *, as_repr: bool = False, file_bytes: bool = False
) -> str:
    """What a plan is made from: the farm as read (its fields' outlines, work angles and
    headland passes, its roads, gates and garage), the fleet, and the solver's settings
    (the command line's included). A stored run made from other inputs is not resumed by
    mistake; a comment, the [dispatcher] section or a time limit changed in the scenario do
    not make another plan, and it is resumed (they refused it: review); nor does the same
    farm saved again, or a field renamed (the farm file's bytes refused it: review).

    The fleet and the solver's settings count by the values not at their defaults
    (:func:`_non_defaults`): a setting an upgrade adds, left at its default, leaves the
    fingerprint as it was, and the run stored before the upgrade is resumed (hashed as
    their ``repr``, it was refused as made from other inputs: --fresh, and the fields
    worked twice). The fingerprints runs stored before had, so that those are resumed too:
    ``file_bytes``, the farm file's bytes for the farm as read (to 2026-11-29 14:00);
    ``as_repr``, those and the settings' ``repr`` (before 2026-11-29)."""
    import hashlib

    h = hashlib.sha256()
    for chunk in _inputs(scenario, args, as_repr=as_repr, file_bytes=file_bytes)[0]:
        h.update(chunk)
    return h.hexdigest()[:16]


def stored_fingerprint(scenario, args: argparse.Namespace) -> str:  # type: ignore[no-untyped-def]
    """The fingerprint a run is stored with: :func:`inputs_fingerprint`, then a short hash
    of each of its inputs by name ("farm=… fleet=… solver=… seed=…"), so that a refused
    resume can say which of them changed (:func:`check_resumable`)."""
    import hashlib

    parts = _inputs(scenario, args)[1]
    named = [f"{name}={hashlib.sha256(data).hexdigest()[:8]}" for name, data in parts.items()]
    return " ".join([inputs_fingerprint(scenario, args), *named])


# Each input of a plan in a refused resume's words (the names of _inputs's parts).
_INPUT_WORDS = {
    "farm": "the farm (its fields, roads, gates or garage)",
    "fleet": "the fleet",
    "solver": "the solver's settings",
    "seed": "the seed",
}


def _inputs(  # type: ignore[no-untyped-def]
    scenario, args: argparse.Namespace, *, as_repr: bool = False, file_bytes: bool = False
) -> tuple[list[bytes], dict[str, bytes]]:
    """What :func:`inputs_fingerprint` hashes, in its order, and the same inputs by name
    (keys of :data:`_INPUT_WORDS`)."""
    import dataclasses

    farm = scenario.farm
    read = [] if file_bytes or as_repr else [_farm_as_read(farm)]
    if file_bytes or as_repr:
        with contextlib.suppress(OSError):
            read = [Path(farm.source).read_bytes()]
    farm_chunks = [
        *read,
        repr([(f.id, round(f.area_m2, 1)) for f in farm.fields]).encode(),
        repr(tuple(round(c, 7) for c in farm.garage_lonlat)).encode(),
    ]
    solver = dataclasses.replace(scenario.solver, time_limit_s=0.0)
    fleet_data, solver_data = _non_defaults(scenario.vehicles), _non_defaults(solver)
    if as_repr:
        settings = [repr(scenario.vehicles).encode(), repr(solver).encode()]
    else:
        both = {"fleet": fleet_data, "solver": solver_data}
        settings = [json.dumps(both, sort_keys=True).encode()]
    seed = getattr(args, "seed", None)
    if seed == scenario.solver.seed:
        seed = None  # --seed as the scenario has it: the same inputs as without it
    seed_chunk = repr(seed).encode()
    parts = {
        "farm": b"".join(farm_chunks),
        "fleet": json.dumps(fleet_data, sort_keys=True).encode(),
        "solver": json.dumps(solver_data, sort_keys=True).encode(),
        "seed": seed_chunk,
    }
    return [*farm_chunks, *settings, seed_chunk], parts


def check_resumable(run, fingerprint: str, scenario, args: argparse.Namespace, where: Path) -> None:  # type: ignore[no-untyped-def]
    """Raise StoreError unless the unfinished ``run`` kept in ``where`` was made from these
    inputs: its fingerprint is ``fingerprint`` (theirs, :func:`stored_fingerprint`), or
    theirs as runs stored before had it. The error names the inputs that changed where
    the run was stored with each one's hash (since 2026-11-29 17:00)."""
    from dispatcher.daemon.store import StoreError

    stored, *stored_parts = run.fingerprint.split()
    now, *now_parts = fingerprint.split()
    if stored == now:
        return
    for before in ({"file_bytes": True}, {"as_repr": True}):
        if stored == inputs_fingerprint(scenario, args, **before):
            return
    changed = sorted(set(stored_parts) - set(now_parts))
    names = [part.split("=")[0] for part in changed if part.split("=")[0] in _INPUT_WORDS]
    what = (
        " and ".join(_INPUT_WORDS[name] for name in names) + " changed since"
        if stored_parts and names
        else "its farm or the options changed since"
    )
    raise StoreError(
        f"{where} holds unfinished run {run.id} (plan {run.job.plan_id}) made from other "
        f"inputs: {args.scenario}, {what}. Serve it with the "
        "same ones to finish it, or add --fresh to start over"
    )


def _farm_as_read(farm) -> bytes:  # type: ignore[no-untyped-def]
    """The farm as planned from, to 1e-7 degrees: each field's id, outline and holes, work
    angle and headland passes; each road; each gate (not names, nor the file's layout)."""

    def ring(coords: Any) -> list[list[float]]:
        return [[round(x, 7), round(y, 7)] for x, y in coords]

    doc = {
        "fields": [
            [
                f.id,
                [ring(f.boundary_lonlat.exterior.coords)]
                + [ring(hole.coords) for hole in f.boundary_lonlat.interiors],
                f.work_angle_deg,
                f.headland_passes,
            ]
            for f in farm.fields
        ],
        "roads": [[r.id, ring(r.line_lonlat.coords)] for r in farm.roads],
        "gates": [[g.field_id, ring([g.lonlat])] for g in farm.gates],
    }
    return json.dumps(doc, sort_keys=True).encode()


def _non_defaults(value: object) -> object:
    """``value`` as plain data (for a fingerprint): a dataclass as its fields not at their
    defaults, by name; sequences and mappings element by element; a float exactly."""
    import dataclasses

    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        plain = {}
        for f in dataclasses.fields(value):
            v = getattr(value, f.name)
            if f.default is not dataclasses.MISSING and v == f.default:
                continue
            if f.default_factory is not dataclasses.MISSING and v == f.default_factory():
                continue
            plain[f.name] = _non_defaults(v)
        return plain
    if isinstance(value, list | tuple):
        return [_non_defaults(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _non_defaults(v) for k, v in value.items()}
    if isinstance(value, float):
        return repr(value)
    if value is None or isinstance(value, str | int | bool):
        return value
    return repr(value)


def plan_scenario(args: argparse.Namespace, scenario=None):  # type: ignore[no-untyped-def]
    """Load the scenario with the command line's overrides (unless given) and plan it,
    saying on stderr what takes time: compiling the solver (first run), the solver."""
    from agrifleet.api import dispatch_for

    scenario = scenario or load_scenario_args(args)
    solver = scenario.solver
    time_limit_s = args.time_limit or solver.time_limit_s
    say = f"planning {len(scenario.farm.fields)} fields for {len(scenario.vehicles)} machines"
    compile_solver()
    bar = ProgressBar(
        solver.generations,
        f"solver: {solver.algorithm}, up to {time_limit_s:g} s",
        time_limit_s,
        waiting=say,
    )
    try:
        return dispatch_for(scenario, args.objective, args.time_limit, args.seed, bar)
    finally:
        bar.close()


def print_plan_table(dispatch) -> None:  # type: ignore[no-untyped-def]
    from agrifleet.api import plan_table

    print(plan_table(dispatch.document), flush=True)


def cmd_plan(args: argparse.Namespace) -> int:
    from dispatcher.mission.plan import write_plan_files

    if args.out is None and not args.json:
        raise ConfigError("plan: where to? give --out DIR (the files) or --json (stdout)")
    if args.out is not None:
        not_a_file(args.out, "--out")  # before the plan: not "File exists" once it is made
    dispatch = plan_scenario(args)
    written = write_plan_files(dispatch, args.out) if args.out is not None else []
    if args.json:  # the plan document alone on stdout; the rest on stderr
        print(dispatch.document.to_json(), flush=True)
        if written:
            print(f"wrote {len(written)} files to {args.out}", file=sys.stderr)
        return EXIT_OK
    print_plan_table(dispatch)
    print(f"wrote {len(written)} files to {args.out}")
    return EXIT_OK


def cmd_serve(args: argparse.Namespace) -> int:
    from dispatcher.daemon.server import DaemonConfig, Dispatcher
    from dispatcher.daemon.store import Store, default_data_dir
    from dispatcher.link.access import access_control, as_hub
    from dispatcher.link.keys import signing_keys
    from dispatcher.tools.replan import replanner_for, replanner_resumed

    scenario = load_scenario_args(args)
    ids = [v.id for v in scenario.vehicles]
    keys = signing_keys(args, scenario, ids)
    zenoh = as_hub(wire.zenoh_options(args, True), access_control(scenario.farm_id, ids))
    zenoh.config()  # a missing certificate or a plain endpoint with --tls: said before planning
    zenoh.check_listen_free()  # and a port another process listens on
    data_dir = made_dir(args.data_dir or default_data_dir(scenario.farm_id), "--data-dir")
    made_dir(args.log_dir, "--log-dir")
    fingerprint = stored_fingerprint(scenario, args)
    store = Store.open(data_dir, scenario.farm_id, args.sync)
    try:
        if args.fresh and (abandoned := store.abandon_unfinished()) is not None:
            print(f"--fresh: run {abandoned} in {store.path} abandoned (kept there as such)")
        run = store.unfinished_run()
        if run is not None:
            check_resumable(run, fingerprint, scenario, args, store.path)
            store.resume_run(run)
            job = run.job
            replanner = replanner_resumed(scenario, job, run.started, run.documents)
            print(f"resuming run {run.id} of plan {job.plan_id} from {store.path}")
        else:
            dispatch = plan_scenario(args, scenario)
            print_plan_table(dispatch)
            job = dispatch.job()
            started = time.time()
            run_id = store.begin_run(job, fingerprint, started)
            print(f"run {run_id} kept in {store.path}")
            replanner = replanner_for(scenario, dispatch, started=started)
        daemon = Dispatcher(
            DaemonConfig(
                job=job,
                zenoh=zenoh,
                log_dir=args.log_dir,
                heartbeat_timeout_s=scenario.watch.lost_after_s,
                stall_after_s=scenario.watch.stall_after_s,
                lost_grace_s=scenario.watch.lost_grace_s,
                alive_timeout_s=scenario.watch.alive_after_s,
                window_items=scenario.watch.window_items,
                topup_lead_s=scenario.watch.topup_lead_s,
                store=store,
                resume=run,
                replanner=replanner,
                keys=keys,
                foxglove=foxglove_address(args),
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
    from dispatcher.config.scenario import load_scenario
    from dispatcher.link.keys import key_path, write_keys

    scenario = load_scenario(args.scenario)
    folder = args.keys or scenario.keys_dir
    if folder is None:
        raise ConfigError(
            f'{args.scenario}: where to? give --keys DIR, or keys = "DIR" in the scenario'
        )
    not_a_file(Path(folder), "--keys" if args.keys else f"{args.scenario}: keys")
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


def cmd_certs(args: argparse.Namespace) -> int:
    from dispatcher.config.scenario import load_scenario
    from dispatcher.link.access import (
        ACL_FILE,
        CA_FILE,
        DEFAULT_HOSTS,
        DISPATCHER,
        OPERATOR,
        ROUTER,
        ZENOHD_FILE,
        make_farm_pki,
    )

    scenario = load_scenario(args.scenario)
    ids = [v.id for v in scenario.vehicles]
    hosts = tuple(args.host or DEFAULT_HOSTS)
    not_a_file(Path(args.tls), "--tls")
    written = make_farm_pki(args.tls, scenario.farm_id, ids, hosts, replace=args.replace)
    for path in written:
        print(f"wrote {path}")
    folder = Path(args.tls)
    print(
        f"farm {scenario.farm_id!r}: certificates for {DISPATCHER}, {ROUTER}, {OPERATOR} and "
        f"{len(ids)} vehicle(s), valid for {', '.join(hosts)}; {len(written)} file(s) new.\n"
        f"Give each machine {folder / CA_FILE} and its own <name>.pem and <name>.key only; "
        f"keep ca.key off the farm network. {folder / ACL_FILE} is who may say what, "
        f"{folder / ZENOHD_FILE} a zenohd router configuration (docs/security.md)."
    )
    return EXIT_OK


def cmd_bridge(args: argparse.Namespace) -> int:
    from dispatcher.tools.bridge import bridge_command

    return bridge_command(args, wire.zenoh_options(args, False, identity=args.vehicle))


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
    foxglove = foxglove_address(args)  # checked before planning too
    made_dir(args.log_dir, "--log-dir")
    dispatch = plan_scenario(args, scenario)
    print_plan_table(dispatch)
    result = run_demo(
        Path(args.scenario),
        dispatch,
        args.speedup,
        args.log_dir,
        faults=faults,
        foxglove=foxglove,
        fields=args.fields,
    )
    print(summary(result.daemon, result))
    print(f"log: {result.daemon.log_path}")
    return result.code


def cmd_router(args: argparse.Namespace) -> int:
    from dispatcher.link.access import ROUTER, as_hub, read_acl
    from dispatcher.tools.router import (
        DEFAULT_ROUTER_ENDPOINT,
        DEFAULT_TLS_ROUTER_ENDPOINT,
        run_router,
    )

    if not args.listen:
        args.listen = [DEFAULT_TLS_ROUTER_ENDPOINT if args.tls else DEFAULT_ROUTER_ENDPOINT]
    options = wire.zenoh_options(args, False, identity=ROUTER)
    if args.tls:
        options = as_hub(options, read_acl(args.tls))
    return run_router(options)


def cmd_review(args: argparse.Namespace) -> int:
    from dispatcher.recording.mcap_file import read_logs
    from dispatcher.review.report import review_contents, review_json, review_table

    log = read_logs(args.logs)  # several files (or a directory) of one run read as one
    if log.note:
        print(f"agrifleet: {log.note}", file=sys.stderr)
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


def exit_codes_text() -> str:
    return "exit codes:\n" + "\n".join(
        f"  {code:<4} {meaning}" for code, meaning in EXIT_CODES.items()
    )


OBJECTIVES = ["makespan", "distance", "time", "fuel", "minmax", "minsum"]
"""What ``--objective`` takes: planner.choices.Objective's names and "minsum" (distance,
TSPLIB's name, as a scenario's ``objective`` takes it)."""


def cmd_bench_peer(args: argparse.Namespace) -> int:
    """`bench mtsp` and `bench farm`: ours and a peer side by side."""
    from dispatcher.tools.bench import Runs, bench_farm, bench_mtsp, parse_cells, parse_farms

    runs = Runs(args.time_limit, args.runs, args.seed, args.algorithm)

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    if args.suite == "mtsp":
        cells = parse_cells(args.cells)
        compile_solver()
        report = bench_mtsp(cells, args.peer, args.objective, runs, progress)
    else:
        farms = parse_farms(args.farms)
        compile_solver()
        report = bench_farm(
            farms, args.peer, runs, progress, args.makespan_slack, args.land_per_field, args.passes
        )
    print(report)
    return EXIT_OK


def cmd_bench_compile(args: argparse.Namespace) -> int:
    from dispatcher.tools.bench_resources import bench_compile

    print(bench_compile(lambda line: print(line, file=sys.stderr, flush=True)))
    return EXIT_OK


def cmd_bench_scale(args: argparse.Namespace) -> int:
    from dispatcher.tools.bench import BenchError
    from dispatcher.tools.bench_resources import bench_scale, scale_instances

    instances = scale_instances(args.instances)
    if args.salesmen < 1:
        raise BenchError(f"-m/--salesmen must be at least 1, not {args.salesmen}")
    if not args.time_limit > 0:
        raise BenchError(f"--time-limit must be positive, not {args.time_limit}")
    compile_solver()
    report = bench_scale(
        instances,
        args.salesmen,
        args.time_limit,
        args.seed,
        args.algorithm,
        args.plot,
        lambda line: print(line, file=sys.stderr, flush=True),
    )
    print(report)
    return EXIT_OK


def add_bench_arguments(p: argparse.ArgumentParser, time_limit: float) -> None:
    p.add_argument("--time-limit", type=seconds, default=time_limit, help="seconds per run")
    p.add_argument("--runs", type=int, default=5, help="our seeds per cell")
    p.add_argument("--seed", type=int, default=1, help="our first seed (and the peer's)")
    add_algorithm_argument(p)


def _positive(text: str, what: str) -> float:
    """``text`` as a finite number > 0, or argparse's error saying it is not ``what``."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"{text} must be {what} > 0")
    return value


FIGURE_FORMATS = ("png", "pdf", "svg", "jpg", "jpeg", "webp", "tif", "tiff", "eps", "ps")
"""What a --plot file may be: formats matplotlib writes, by the name's suffix."""


def figure_file(text: str) -> Path:
    """A picture to write (argparse's ``type``): a name without a suffix is a PNG; one with
    a suffix matplotlib cannot write is refused (it was a matplotlib traceback)."""
    path = Path(text)
    suffix = path.suffix.lower().lstrip(".")
    if not suffix:
        return path.with_name(path.name + ".png")
    if suffix not in FIGURE_FORMATS:
        raise argparse.ArgumentTypeError(
            f"{text}: not a picture format matplotlib writes ({', '.join(FIGURE_FORMATS)})"
        )
    return path


def seconds(text: str) -> float:
    """An argument that is a number of seconds > 0 (argparse's ``type``)."""
    return _positive(text, "a number of seconds")


def speedup_factor(text: str) -> float:
    """A simulator's speedup: a number > 0 (argparse's ``type``)."""
    return _positive(text, "a number")


def plan_seconds(text: str) -> float:
    """A plan's time limit: seconds within the bounds of ``[solver] time_limit_s``."""
    from dispatcher.config.scenario import LIMITS

    value, bounds = seconds(text), LIMITS["time_limit_s"]
    if not bounds.low <= value <= bounds.high:
        raise argparse.ArgumentTypeError(
            f"{text} is out of bounds: {bounds.low:g} to {bounds.high:g} s "
            f"({bounds.why_low if value < bounds.low else bounds.why_high})"
        )
    return value


def add_algorithm_argument(p: argparse.ArgumentParser) -> None:
    from planner.choices import ALGORITHMS, DEFAULT_ALGORITHM

    p.add_argument(
        "--algorithm",
        choices=ALGORITHMS,
        default=DEFAULT_ALGORITHM,
        help=f"hybrid (IGHOA's shape with moves between routes, Or-opt and an iterated local "
        f"search, docs/ighoa.md), ighoa (the paper's) or ga (plain genetic algorithm); "
        f"default {DEFAULT_ALGORITHM}",
    )


def build_parser() -> argparse.ArgumentParser:
    from agrifleet.version import __version__

    parser = argparse.ArgumentParser(
        prog="agrifleet",
        description=__doc__,
        epilog=exit_codes_text() + "\n\n`agrifleet COMMAND --help` for a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"agrifleet {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser(
        "demo", help="plan, simulate the fleet and dispatch, end to end, on this computer"
    )
    add_plan_arguments(p, scenario_default="the demo farm, config/changji.toml")
    p.add_argument(
        "--speedup",
        type=speedup_factor,
        default=None,
        metavar="X",
        help="simulated seconds per wall second, > 0 (default: fit the run into ~45 s, at "
        "most 1200x)",
    )
    add_log_dir_argument(p)
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
        help="every radio loses this share (0..1) of frames",
    )
    g.add_argument(
        "--duplicate",
        type=float,
        default=0.0,
        metavar="P",
        help="every radio sends this share (0..1) of frames twice",
    )
    g.add_argument(
        "--delay", type=float, default=0.0, metavar="MS", help="frames arrive 0 to MS ms late"
    )
    g.add_argument("--radio-seed", type=int, default=1, metavar="N", help="the radios' seed")
    add_foxglove_argument(p, on_by_default=True)
    p.set_defaults(handler=cmd_demo)

    p = sub.add_parser(
        "plan", help="plan a farm: plan.json, missions per machine, map.png (or --json)"
    )
    add_plan_arguments(p)
    p.add_argument(
        "--out", type=Path, metavar="DIR", help="write plan.json, the missions and map.png here"
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print the plan document (plan.json) on stdout, and nothing else there",
    )
    p.set_defaults(handler=cmd_plan)

    p = sub.add_parser(
        "serve",
        help="the dispatcher daemon: plan (or resume the unfinished run), upload, follow, record",
    )
    add_plan_arguments(p)
    add_log_dir_argument(p)
    p.add_argument(
        "--data-dir",
        type=Path,
        metavar="DIR",
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
        help="SQLite synchronous mode: full (default) survives a power cut, normal only a "
        "crash of the dispatcher (docs/restart.md)",
    )
    add_signing_arguments(p)
    add_foxglove_argument(p, on_by_default=False)
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

    p = sub.add_parser(
        "certs",
        help="make the farm's TLS certificates and Zenoh access-control list (docs/security.md)",
    )
    p.add_argument("scenario", type=Path, help="scenario TOML: the farm and its vehicles")
    p.add_argument("--tls", metavar="DIR", required=True, help="folder to write them into")
    p.add_argument(
        "--host",
        action="append",
        metavar="NAME",
        help="a name or address the dispatcher or router is reached at (repeat; default "
        "localhost, 127.0.0.1 and ::1): connectors check the listener's certificate for it",
    )
    p.add_argument("--replace", action="store_true", help="new CA, certificates and keys for all")
    p.set_defaults(handler=cmd_certs)

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
    p.add_argument(
        "--plot",
        type=figure_file,
        metavar="FILE.png",
        help="write a map and Gantt chart here (PNG, or .pdf, .svg, ...)",
    )
    p.set_defaults(handler=cmd_review)

    p = sub.add_parser("router", help="a Zenoh router (for several gateways or farms)")
    wire.add_zenoh_arguments(p, mode="router", modes=("router",))
    p.set_defaults(handler=cmd_router)

    p = sub.add_parser(
        "warm",
        help="compile the solver's kernels now, once for this install (make does it after "
        "installing; otherwise the first plan does)",
    )
    p.set_defaults(handler=cmd_warm)

    p = sub.add_parser("mtsp", help="solve a TSPLIB instance as a multiple-TSP")
    p.add_argument("instance", type=Path, help="TSPLIB .tsp file; node 1 is the depot")
    p.add_argument(
        "-m", "--salesmen", type=int, required=True, metavar="M", help="number of salesmen"
    )
    p.add_argument(
        "--objective",
        choices=["minsum", "minmax"],
        default="minsum",
        help="total distance (minsum, default) or the longest route (minmax)",
    )
    add_algorithm_argument(p)
    p.add_argument(
        "--time-limit", type=seconds, default=None, metavar="S", help="solver wall-clock seconds"
    )
    p.add_argument("--generations", type=int, default=2000, help="at most this many (default 2000)")
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    p.add_argument(
        "--distance",
        choices=["euclidean", "tsplib"],
        default="euclidean",
        help="real-valued distances (default) or TSPLIB's rounded integers",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=cmd_mtsp)

    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="suite", required=True, metavar="SUITE")
    p = bench_sub.add_parser("paper", help="rerun the paper's tables beside its figures")
    p.add_argument(
        "--tables", default="2,3,4,5,8,9,10", help="comma-separated table numbers (default all)"
    )
    p.add_argument("--runs", type=int, default=5, help="seeds per cell (default 5)")
    p.add_argument(
        "--time-limit", type=seconds, default=30.0, metavar="S", help="seconds per run (default 30)"
    )
    p.add_argument(
        "--generations", type=int, default=2000, help="at most this many per run (default 2000)"
    )
    p.add_argument(
        "--algorithm",
        choices=["ighoa", "hybrid"],
        default="ighoa",
        help="for the TSPLIB tables: ighoa (the paper's own, default) or hybrid (ours); the "
        "farm tables 8-10 run the paper's IGHOA and GA",
    )
    p.add_argument("--out", type=Path, default=None, metavar="FILE.md", help="also write it here")
    p.set_defaults(handler=cmd_bench_paper)
    from dispatcher.tools.bench import DEFAULT_CELLS, DEFAULT_FARMS, PEERS

    p = bench_sub.add_parser("mtsp", help="ours and OR-Tools or PyVRP on TSPLIB mTSP cells")
    p.add_argument("--peer", choices=PEERS, default=None, help="the peer solver (default none)")
    p.add_argument("--cells", default=DEFAULT_CELLS, help="INSTANCE:M,… (default %(default)s)")
    p.add_argument(
        "--objective",
        choices=["minsum", "minmax"],
        default="minsum",
        help="total length, or the longest route (default minsum)",
    )
    add_bench_arguments(p, 10.0)
    p.set_defaults(handler=cmd_bench_peer)
    p = bench_sub.add_parser("farm", help="ours and OR-Tools on generated farms (makespan)")
    p.add_argument("--peer", choices=["ortools"], default=None, help="the peer (default none)")
    p.add_argument("--farms", default=DEFAULT_FARMS, help="FIELDSxMACHINES,… (default %(default)s)")
    p.add_argument(
        "--makespan-slack",
        type=float,
        default=0.0,
        metavar="F",
        help=f"ours ε-lexicographic: in the last {100 * SLACK_SHARE:g} %% of the time a makespan "
        "up to (1 + F) x the best counts as equal and the road km decide (default 0: makespan, "
        "then road km)",
    )
    p.add_argument(
        "--land-per-field",
        type=float,
        default=None,
        metavar="KM2",
        help="how spread out the farm is: square kilometres of land a field (default 4: the "
        "fields cover 3.5 %% of the land; 0.4: 35 %%)",
    )
    p.add_argument(
        "--passes",
        type=int,
        default=1,
        metavar="N",
        help="how many times each field is worked: its hours N times over, so that travel "
        "weighs less (default 1; 6 makes a 500x30 farm's makespan ~320 h, issue 12's scale)",
    )
    add_bench_arguments(p, 60.0)
    p.set_defaults(handler=cmd_bench_peer)
    p = bench_sub.add_parser(
        "compile", help="seconds to compile the kernels (empty numba cache), then to load them"
    )
    p.set_defaults(handler=cmd_bench_compile)
    from dispatcher.tools.bench_resources import SCALE_INSTANCES

    p = bench_sub.add_parser(
        "scale", help="seconds per generation and peak memory as n grows (log-log plot)"
    )
    p.add_argument("--instances", default=SCALE_INSTANCES, help="INSTANCE,… (default %(default)s)")
    p.add_argument("-m", "--salesmen", type=int, default=3, help="salesmen (default 3)")
    p.add_argument(
        "--time-limit", type=seconds, default=20.0, metavar="S", help="seconds per instance (20)"
    )
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    add_algorithm_argument(p)
    p.add_argument(
        "--plot",
        type=figure_file,
        default=None,
        metavar="FILE.png",
        help="also draw the log-log plot",
    )
    p.set_defaults(handler=cmd_bench_scale)

    return parser


def add_foxglove_argument(p: argparse.ArgumentParser, on_by_default: bool) -> None:
    """``--foxglove [HOST:]PORT`` (and ``--no-foxglove`` where it is on by default)."""
    from dispatcher.recording.address import DEFAULT_HOST, DEFAULT_PORT

    default = f"{DEFAULT_HOST}:{DEFAULT_PORT}" if on_by_default else None
    g = p.add_argument_group("live view (docs/foxglove.md)")
    g.add_argument(
        "--foxglove",
        metavar="[HOST:]PORT",
        default=default,
        help="serve the fleet live to Foxglove over its WebSocket protocol on this address "
        f"(HOST defaults to {DEFAULT_HOST}; 0.0.0.0 for other machines; PORT 0: any free one)"
        + (f"; default {default}" if default else "; default: off"),
    )
    if on_by_default:
        g.add_argument(
            "--no-foxglove",
            dest="foxglove",
            action="store_const",
            const=None,
            help="no live view",
        )


def foxglove_address(args: argparse.Namespace) -> tuple[str, int] | None:
    """The live view's (host, port) from ``--foxglove``, or None; a bad value exits 2."""
    from dispatcher.link.wire import is_loopback
    from dispatcher.recording.address import parse_address

    if not args.foxglove:
        return None
    host, port = parse_address(args.foxglove)
    if not is_loopback(f"tcp/{host}:{port}"):
        logging.getLogger("agrifleet").warning(
            "--foxglove %s: the live view asks no one who they are: anyone who reaches %s sees "
            "the fleet (it takes no commands); put it behind a VPN or an SSH tunnel",
            args.foxglove,
            host,
        )
    return host, port


def add_plan_arguments(p: argparse.ArgumentParser, scenario_default: str | None = None) -> None:
    """The scenario and the options that change a plan (plan, serve, demo)."""
    if scenario_default is None:
        p.add_argument("scenario", type=Path, help="scenario TOML (see config/README.md)")
    else:
        p.add_argument(
            "scenario",
            type=Path,
            nargs="?",
            default=None,
            help=f"scenario TOML (see config/README.md; default {scenario_default})",
        )
    p.add_argument(
        "--fields",
        type=Path,
        metavar="FARM",
        help="a farm file replacing the scenario's: GeoJSON, KML, shapefile (.shp, folder or "
        ".zip), GeoPackage, ISOXML TASKDATA.XML (docs/farm-files.md); the farm id becomes its "
        "name",
    )
    p.add_argument(
        "--id-field",
        metavar="NAME",
        help="the property that holds a field's id (default: the first of id, field_id, "
        "fieldid, name)",
    )
    p.add_argument(
        "--name-field",
        metavar="NAME",
        help="the property that holds a field's name (default: the first of name, "
        "field_name, fieldname, designator, title; else its id)",
    )
    p.add_argument(
        "--machines", type=int, metavar="K", help="use the first K machines of the fleet"
    )
    p.add_argument(
        "--objective",
        choices=OBJECTIVES,
        help="what to minimise: makespan (when the farm is done), distance on roads (minsum), "
        "time or fuel of the fleet, minmax (the longest route); default: the scenario's",
    )
    p.add_argument(
        "--time-limit",
        type=plan_seconds,
        metavar="S",
        help="wall-clock seconds for the whole plan, 0.1 to 3600 (default: the scenario's "
        "time_limit_s)",
    )
    p.add_argument("--seed", type=int, help="the solver's random seed (default: the scenario's)")
    p.add_argument(
        "--finish-within",
        type=float,
        metavar="H",
        help="a deadline (hybrid, makespan): the shortest roads among plans done within H "
        "hours; 0: none (default: the scenario's finish_within_h)",
    )


def not_a_file(path: Path, flag: str) -> None:
    """A :class:`ConfigError` naming ``flag`` when a file is where a directory is to be."""
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{flag} {path}: not a directory (a file of that name is there)")


def made_dir(path: Path, flag: str) -> Path:
    """``path`` made a directory (with its parents) before anything is planned or written,
    or a :class:`ConfigError` naming ``flag``: a file there, no permission, ..."""
    not_a_file(path, flag)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(
            f"{flag} {path}: cannot be made a directory ({exc.strerror or exc})"
        ) from exc
    return path


def add_log_dir_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--log-dir",
        type=Path,
        default=Path("logs"),
        metavar="DIR",
        help="write the run's MCAP log here (default logs/)",
    )


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["sim"]:
        # Straight to the simulator's own parser: argparse would take `sim --help` (any
        # option right after `sim`) as agrifleet's.
        return cmd_sim(argparse.Namespace(rest=argv[1:]))
    args = build_parser().parse_args(argv)
    # Daemons log what they do; interactive commands keep the terminal for their own output.
    quiet = args.command in ("demo", "plan", "mtsp", "bench", "review", "warm")
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else (logging.WARNING if quiet else logging.INFO),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    restore_sigterm = sigterm_interrupts()
    try:
        return int(args.handler(args))
    except (PlannerError, DispatcherError) as exc:
        from dispatcher.daemon.store import StoreWriteError

        print(f"agrifleet: error: {exc}", file=sys.stderr)
        return EXIT_STATE_UNWRITTEN if isinstance(exc, StoreWriteError) else EXIT_BAD_INPUT
    except BrokenPipeError:
        # Output piped into `head` and the like: stop quietly, as Unix tools do.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except OSError as exc:
        # A path given that cannot be written or read (--out an existing file, a folder
        # that is not there): named, without a traceback.
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"agrifleet: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("agrifleet: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except SystemError as exc:
        # Ctrl-C or SIGTERM while a numba kernel called back into Python (the solver's
        # clock) comes out as a SystemError caused by the KeyboardInterrupt.
        if not isinstance(exc.__cause__, KeyboardInterrupt):
            raise
        print("agrifleet: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        restore_sigterm()


if __name__ == "__main__":
    sys.exit(main())
