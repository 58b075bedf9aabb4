"""The architecture as rules a test can check (issue 13): no import cycles, pure cores stay pure, the walls
between the companion, the bundled vehicle and the lab hold, and the package list ships every package.

Imports are read from the source (AST), including those inside functions: a lazy import is still a
dependency. ``from pkg import name`` counts as importing ``pkg.name`` when that is a module of ours.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("companion", "sim_bridge", "lab")

#: Pure cores: no I/O frameworks, however indirectly.
PURE_PREFIXES = ("companion.core", "companion.planning", "companion.control", "companion.estimation",
                 "companion.autopilots", "companion.flight.core", "companion.flight.sequence",
                 "companion.flight.health", "companion.flight.requests", "companion.report.metrics",
                 "companion.mavlink_io.telemetry", "companion.mavlink_io.events",  # typed telemetry (estimation)
                 "companion.mavlink_io.mission_client",  # the mission download's state machine (typed events in/out)
                 # the pilot and everything it decides with (the runners around it are not pure)
                 "companion.flight.pilot", "companion.flight.phase", "companion.flight.failsafes",
                 "companion.flight.sensing", "companion.flight.core_orders",
                 "companion.flight.mode_goal", "companion.flight.setup", "companion.flight.mission_frame",
                 "companion.flight.obstacle_view", "companion.flight.flight_record", "companion.flight.facts",
                 "companion.flight.loop_stats", "companion.flight.arrival", "companion.flight.command",
                 "companion.flight.loop_margin", "companion.flight.liftoff",
                 "companion.report.scoring", "companion.flight.legs",
                 "companion.flight.operator",  # the ground station's commands, decided (issue 27)
                 "companion.flight.identification",  # the payload identified, and what the flight does with it
                 "companion.perception")  # scans into a local map: sockets and sessions feed it from outside
IO_FRAMEWORKS = ("asyncio", "pymavlink", "zenoh", "socket")
#: What the bundled vehicle may use of the companion: the shared model and MAVLink helpers.
SIM_MAY_IMPORT = ("companion.core", "companion.mavlink_io.codec", "companion.mavlink_io.signing",
                  "companion.mavlink_io.framing",  # MAVLink frames out of a serial stream (sitl --serial)
                  "companion.autopilots", "companion.errors", "companion.config", "companion",
                  "companion.proclife",  # children tied to their parent's life (no I/O of its own)
                  "companion.zenoh_io.schema")  # the Zenoh key expressions and payloads (the raw scan)


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    if parts[0] == "config":  # shipped as companion.configs
        parts = ["companion", "configs", *parts[1:]]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in (*PACKAGES, "config"):
        for f in (ROOT / pkg).rglob("*.py"):
            out[_module_name(f)] = f
    return out


MODULES = _modules()


def _imports(name: str) -> set[str]:
    """Every module (ours or third-party top-level) that module ``name`` imports, anywhere in its body."""
    path = MODULES[name]
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                out.add(a.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join([*base, node.module] if node.module else base)
            else:
                mod = node.module or ""
            for a in node.names:
                full = f"{mod}.{a.name}"
                out.add(full if full in MODULES else mod)
    return {m for m in out if m and m != "__future__"}


GRAPH = {m: _imports(m) for m in MODULES}


def _ours(m: str) -> bool:
    return m.split(".")[0] in PACKAGES


def _closure(start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        m = todo.pop()
        for d in GRAPH.get(m, ()):
            if d not in seen:
                seen.add(d)
                if d in GRAPH:
                    todo.append(d)
    return seen


def test_no_import_cycles():
    """Tarjan's strongly connected components over our modules: every component is a single module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []
    counter = [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in GRAPH[v]:
            if w not in GRAPH:
                continue
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(GRAPH):
        if v not in index:
            strong(v)
    assert cycles == []


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m.startswith(PURE_PREFIXES)))
def test_pure_cores_import_no_io(module):
    deps = _closure(module)
    bad = sorted(d for d in deps if d.split(".")[0] in IO_FRAMEWORKS)
    assert not bad, f"{module} reaches {bad}"
    impure = sorted(d for d in deps if _ours(d) and not d.startswith((*PURE_PREFIXES, "companion.errors",
                                                                       "companion.config"))
                    and d not in ("companion",))
    assert not impure, f"{module} imports non-pure modules {impure}"


def test_companion_never_imports_the_simulator_or_the_lab_except_from_the_entry_point():
    offenders = {m: sorted(d for d in deps if d.split(".")[0] in ("sim_bridge", "lab"))
                 for m, deps in GRAPH.items() if m.startswith("companion") and m != "companion.cli.main"}
    assert {m: d for m, d in offenders.items() if d} == {}


def test_the_lab_flies_through_the_launch_api_not_the_command_line():
    """lab builds its flights in code (companion.launch.FlySpec), never from the CLI's argument objects."""
    offenders = {m: sorted(d for d in deps if d.startswith("companion.cli"))
                 for m, deps in GRAPH.items() if m.startswith("lab")}
    assert {m: d for m, d in offenders.items() if d} == {}


def test_the_flight_runners_are_thin_and_the_pilot_is_pure_of_the_clock():
    """The pilot and the sequence read no clock of their own: time comes in as arguments."""
    for module in ("companion.flight.pilot", "companion.flight.sequence", "companion.flight.core"):
        src = MODULES[module].read_text()
        assert "time.monotonic" not in src and "time.perf_counter" not in src, module


def test_the_simulator_uses_only_the_shared_model_and_mavlink_helpers():
    used = {d for m, deps in GRAPH.items() if m.startswith("sim_bridge") for d in deps if d.startswith("companion")}
    bad = sorted(d for d in used if not (d in SIM_MAY_IMPORT or d.startswith(tuple(p + "." for p in SIM_MAY_IMPORT
                                                                                      if p != "companion"))))
    assert bad == []


def test_pyproject_lists_every_package():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    on_disk = {_module_name(f.parent / "__init__.py") for pkg in (*PACKAGES, "config")
               for f in (ROOT / pkg).rglob("__init__.py")}
    assert listed == on_disk
    assert cfg["package-dir"] == {"companion.configs": "config"}


def test_files_that_fly_real_processes_through_the_lab_run_serially():
    """``from lab import faults`` starts vehicles, proxies and companions on the wall clock without the test file
    saying so: such a file must still run in the serial phase (its jitter flight missed its 0.5 m beside another
    worker's flights in CI, 2026-12-03). A file of pure math must not."""
    from conftest import starts_processes

    tests = Path(__file__).parent
    assert starts_processes(tests / "test_faults.py")
    assert not starts_processes(tests / "test_model_lagrangian.py")
    assert not starts_processes(tests / "test_wind_push.py")  # lab.inprocess flies in this process
