"""Import rules that keep the data flow one-way and the MAVLink knowledge in one place (the safe-simple issue).

* pymavlink is imported only by the one module per side that talks MAVLink (the bridge's ``mavlink_link`` with
  its request/reply half ``vehicle_requests``, the sim's ``mavlink_vehicle`` with the ``vehicle_*`` parts it is
  split into, ``px4_hil``, the simulator genuine PX4 connects to, and ``genuine_observer``, a ground station's view of
  a genuine SITL) and by the benchmark package
  (``mavastsm/bench``, whose naive-client baseline *is* a plain pymavlink loop); no module writes the environment at import, and ``MAVLINK20`` is set
  only where a pymavlink connection is opened, just before it.
* autopilot knowledge lives in one adapter per autopilot (``mavastsm/bridge/autopilots/``): they alone may read
  pymavlink's mode tables of their autopilot, and nothing outside them compares a value with an autopilot's name.
* the bridge stands in floors that follow the data (``mavastsm/bridge/link``, ``autopilots``, ``cycle``, ``session``,
  ``record``; ``BRIDGE_FLOORS`` below): each imports only the floors it reads, none imports the facade above them.
* the benchmarks import the package, never the tests: a harness both need lives in the package.
* the dashboard reads telemetry only: it imports nothing of the bridge, the controllers, the sim or MAVLink.
* the controllers (``mavastsm/control``) import nothing of the bridge, the sim, the dashboard or MAVLink, and no
  config loading: a law is built from a gains object; only the factory ``from_config`` (next to the registry in
  ``mavastsm/control/__init__.py``) reads YAML, with an import local to it.
* the sim (``sim/``, installed as ``mavastsm_sim``) stands below the package's commands: it imports only the
  ``mavastsm`` foundations in ``FOUNDATIONS`` (frames, errors, config loading, scenarios, the Solo model, MAVLink
  framing and signing, option types), and those import only each other; nothing of the bridge, the dashboard, the
  CLI or an application. The CLI loads the sim's command through ``importlib``, so the import graph counts a module
  name handed to ``importlib.import_module`` as an import, and it has no cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAVLINK_MODULES = {"mavastsm/bridge/link/mavlink_link.py", "sim/mavlink_vehicle.py",
                   "sim/px4_hil.py"}  # PX4's simulator interface: its wire to genuine PX4 is MAVLink (HIL_*)
# the bridge's link and its request/reply half (commands and parameters, answers awaited), built by the link over it
MAVLINK_MODULES |= {"mavastsm/bridge/link/vehicle_requests.py"}
# the parts MavlinkVehicle is split into (issue 29, one job each): each speaks MAVLink through the vehicle's one link
MAVLINK_MODULES |= {f"sim/vehicle_{part}.py" for part in ("link", "inbound", "commands", "params", "streams",
                                                          "telemetry", "startup")}
# the ground station's view of a genuine SITL that the genuine-autopilot tests and the benchmarks share
MAVLINK_MODULES |= {"sim/genuine_observer.py"}
# one adapter per autopilot: each reads its autopilot's mode table from pymavlink (the library's copy, not ours)
ADAPTER_FOLDER = "mavastsm/bridge/autopilots/"
MAVLINK_MODULES |= {f"{ADAPTER_FOLDER}{name}.py" for name in ("ardupilot", "px4")}
# what the sim may import of mavastsm: pure data, math, config loading and MAVLink framing shared by both sides
FOUNDATIONS = {"mavastsm", "mavastsm.errors", "mavastsm.frames", "mavastsm.ap_math", "mavastsm.config_loading",
               "mavastsm.references", "mavastsm.scenarios", "mavastsm.solo_model", "mavastsm.signing",
               "mavastsm.mavlink_datagram", "mavastsm.option_types", "mavastsm.processes",
               "mavastsm.readme_commands"}
PACKAGE_FILES = sorted(list((ROOT / "mavastsm").rglob("*.py")) + list((ROOT / "sim").rglob("*.py")))


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _imports(path: Path) -> set[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved against its package)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    rel = _rel(path)
    package = rel[:-3].replace("/", ".").replace("sim.", "mavastsm_sim.", 1) if rel.startswith("sim/") else rel[:-3].replace("/", ".")
    if package == "sim":
        package = "mavastsm_sim"
    parts = package.split(".")
    if not path.name == "__init__.py":
        parts = parts[:-1]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = parts[:len(parts) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.add(name)
            out.update(f"{name}.{a.name}" for a in node.names)
    return out


def _module_name(path: Path) -> str:
    """The name ``path`` is imported as (``sim/`` is installed as ``mavastsm_sim``)."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    parts[0] = "mavastsm_sim" if parts[0] == "sim" else parts[0]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in PACKAGE_FILES}


def _imported_by_name(path: Path) -> set[str]:
    """Modules of the tree ``path`` loads by name: string constants naming one, in a module that calls
    ``importlib.import_module`` (the CLI's lazy subcommand table)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    calls = any(isinstance(n, ast.Attribute) and n.attr == "import_module" for n in ast.walk(tree))
    return {n.value for n in ast.walk(tree) if calls and isinstance(n, ast.Constant) and n.value in MODULES}


def _import_graph() -> dict[str, set[str]]:
    """module -> the modules of the tree it imports (anywhere in the file, importlib edges included)."""
    return {name: {i for i in _imports(p) | _imported_by_name(p) if i in MODULES and i != name}
            for name, p in MODULES.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per back edge met in a depth-first walk of ``graph`` (empty when it has none)."""
    found, state = [], {}  # state: 1 on the current path, 2 done

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                found.append(path[path.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    return found


def test_the_import_graph_sees_the_modules_the_cli_loads_through_importlib():
    graph = _import_graph()
    assert {"mavastsm_sim.command", "mavastsm.bridge.command", "mavastsm.demo"} <= graph["mavastsm.cli"]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == [["a", "b", "c", "a"]]


def test_no_import_cycle_importlib_edges_included():
    """A cycle hides a layer broken (the sim's command once imported ``mavastsm.cli``, which loads it)."""
    cycles = _cycles(_import_graph())
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


#: the bridge's floors (mavastsm/bridge/<floor>/) and the floors each may import, its own included. Data flows
#: link -> autopilot -> cycle -> session -> record; the session drives the cycle and writes the record; the link, the
#: record and the configuration import nothing else of the bridge. The facade above them (bridge_api, flight_plan,
#: vehicle_actions, supervision, run_record, command) may import any floor; no floor imports the facade.
BRIDGE_FLOORS = {
    "bridge_config": set(),
    "link": {"link"},
    "autopilots": {"autopilots", "link", "bridge_config"},
    "cycle": {"cycle", "link", "autopilots", "bridge_config"},
    "record": {"record"},
    "session": {"session", "cycle", "link", "record", "bridge_config"},
}


def _bridge_floor(module: str) -> str | None:
    """'cycle' for mavastsm.bridge.cycle.safety, 'bridge_config' for that module, None for the facade."""
    parts = module.split(".")
    if parts[:2] != ["mavastsm", "bridge"] or len(parts) < 3:
        return None
    return parts[2] if parts[2] in BRIDGE_FLOORS else None


def test_the_bridge_floors_import_only_the_floors_beneath_them():
    graph = _import_graph()
    floors_seen = {f for f in map(_bridge_floor, MODULES) if f}
    assert floors_seen == set(BRIDGE_FLOORS), floors_seen  # a floor renamed or added must be placed here
    bad = []
    for name in sorted(n for n in MODULES if _bridge_floor(n)):
        floor = _bridge_floor(name)
        for imported in sorted(i for i in graph[name] if i.startswith("mavastsm.bridge")):
            target = _bridge_floor(imported)
            if target not in BRIDGE_FLOORS[floor] and target != floor:
                bad.append(f"{_rel(MODULES[name])} ({floor}) imports {imported} ({target or 'the facade'})")
    assert not bad, "\n".join(bad)


def test_the_sim_imports_only_mavastsm_foundations():
    graph = _import_graph()
    for name in sorted(n for n in MODULES if n.startswith("mavastsm_sim")):
        bad = sorted(i for i in graph[name] if not i.startswith("mavastsm_sim") and i not in FOUNDATIONS)
        assert not bad, f"{_rel(MODULES[name])} imports {bad}; the sim may import only {sorted(FOUNDATIONS)}"


def test_the_foundations_import_only_foundations():
    graph = _import_graph()
    for name in sorted(FOUNDATIONS):
        bad = sorted(graph[name] - FOUNDATIONS)
        assert not bad, f"{_rel(MODULES[name])} imports {bad}: a foundation imports only foundations"


def test_importing_every_sim_module_loads_no_mavastsm_module_but_foundations():
    """The same rule at run time (what an import inside a function or a computed name would slip past the scan)."""
    import subprocess
    import sys

    sim_modules = sorted(n for n in MODULES if n.startswith("mavastsm_sim") and not n.endswith("__main__"))
    code = (f"import importlib, sys\nfor m in {sim_modules!r}:\n    importlib.import_module(m)\n"
            "print(','.join(sorted(m for m in sys.modules if m.split('.')[0] == 'mavastsm')))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert set(loaded.split(",")) - {"mavastsm.configs"} <= FOUNDATIONS, loaded


def test_pymavlink_only_in_the_link_modules_and_the_benchmarks():
    offenders = [_rel(p) for p in PACKAGE_FILES
                 if any(i == "pymavlink" or i.startswith("pymavlink.") for i in _imports(p))
                 and _rel(p) not in MAVLINK_MODULES and not _rel(p).startswith("mavastsm/bench/")]
    assert not offenders, f"pymavlink imported outside the link modules: {offenders}"


def test_only_the_adapters_compare_with_an_autopilots_name():
    """``x == "PX4"`` or ``"ArduPilot" != y`` outside the adapters is autopilot knowledge in the wrong place: the
    profile an adapter builds (``AutopilotProfile``) says what differs."""
    names = {"ArduPilot", "PX4", "ArduCopter"}
    offenders = []
    for path in PACKAGE_FILES:
        if _rel(path).startswith(ADAPTER_FOLDER) or not _rel(path).startswith("mavastsm/"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Compare) and any(isinstance(c, ast.Constant) and c.value in names
                                                     for c in [node.left, *node.comparators]):
                offenders.append(f"{_rel(path)}:{node.lineno}")
    assert not offenders, f"an autopilot's name compared outside mavastsm/bridge/autopilots/: {offenders}"


def test_only_the_output_gate_builds_an_admitted_setpoint():
    """What the session sends without a second check (``safety.AdmittedSetpoint``) can only come from the gate."""
    builders = [f"{_rel(path)}:{node.lineno}" for path in PACKAGE_FILES
                for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) == "AdmittedSetpoint"]
    assert len(builders) == 1 and builders[0].startswith("mavastsm/bridge/cycle/safety.py:"), builders


def _module_level_environ_writes(path: Path) -> list[int]:
    """Lines of statements run at import (module body, outside any def/class) that write ``os.environ``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    lines = []

    def visit(node):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            return
        if isinstance(node, (ast.Assign, ast.AugAssign, ast.Delete)):
            targets = node.targets if isinstance(node, (ast.Assign, ast.Delete)) else [node.target]
            if any(isinstance(t, ast.Subscript) and ast.unparse(t.value) == "os.environ" for t in targets):
                lines.append(node.lineno)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and ast.unparse(node.func.value) == "os.environ" \
                and node.func.attr in ("setdefault", "update", "pop", "clear", "__setitem__"):
            lines.append(node.lineno)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return lines


def test_no_module_changes_the_environment_at_import():
    offenders = {_rel(p): lines for p in PACKAGE_FILES if (lines := _module_level_environ_writes(p))}
    assert not offenders, f"os.environ written at import (do it where it is needed, in a function): {offenders}"


def test_mavlink20_is_set_only_where_a_pymavlink_connection_is_opened():
    """pymavlink selects MAVLink 1 or 2 from MAVLINK20 per process; only code that opens a ``mavutil`` connection
    needs it (the bridge's link, at connection time, the naive benchmark client and the genuine SITL's observer);
    the sim and the bench stub build their MAVLink objects from the v20 dialect module directly."""
    setters = {_rel(p) for p in PACKAGE_FILES if "MAVLINK20" in p.read_text(encoding="utf-8")
               and "os.environ" in p.read_text(encoding="utf-8")}
    assert setters <= {"mavastsm/bridge/link/mavlink_link.py", "mavastsm/bench/clients.py", "sim/genuine_observer.py"}, setters


def test_the_benchmarks_import_the_package_never_the_tests():
    """A harness both need lives in the package (the lockstep pair, the genuine SITL's observer): no benchmark puts
    a folder of tests/ on sys.path or imports a module that only tests/ holds."""
    test_modules = {p.stem for p in (ROOT / "tests").rglob("*.py")} - {"__init__"}
    package_modules = {name.rsplit(".", 1)[-1] for name in MODULES}
    offenders = []
    for p in sorted((ROOT / "benchmarks").glob("*.py")):
        source = p.read_text(encoding="utf-8")
        if '"tests"' in source or "'tests'" in source:
            offenders.append(f"{_rel(p)}: names the tests folder")
        offenders += [f"{_rel(p)} imports {name}" for name in sorted(_imports(p))
                      if "." not in name and name in test_modules - package_modules]
    assert not offenders, offenders


def test_the_dashboard_reads_telemetry_only():
    forbidden = ("mavastsm.bridge", "mavastsm.control", "mavastsm.offline", "mavastsm_sim", "pymavlink")
    for p in (ROOT / "mavastsm" / "dashboard").glob("*.py"):
        bad = sorted(i for i in _imports(p) if i.startswith(forbidden))
        assert not bad, f"{_rel(p)} imports {bad}"


def test_the_controllers_know_nothing_of_the_link_the_sim_or_the_dashboard():
    forbidden = ("mavastsm.bridge", "mavastsm.dashboard", "mavastsm_sim", "pymavlink", "mavastsm.offline")
    for p in (ROOT / "mavastsm" / "control").glob("*.py"):
        bad = sorted(i for i in _imports(p) if i.startswith(forbidden))
        assert not bad, f"{_rel(p)} imports {bad}"


def test_the_controllers_read_no_yaml_except_in_the_factory():
    for p in (ROOT / "mavastsm" / "control").glob("*.py"):
        tree = ast.parse(p.read_text(encoding="utf-8"))
        allowed = set()
        if p.name == "__init__.py":
            factory = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "from_config"]
            assert len(factory) == 1, "mavastsm/control/__init__.py: the from_config factory is missing"
            allowed = {id(n) for n in ast.walk(factory[0])}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                names = {node.module or ""}
            elif isinstance(node, ast.Import):
                names = {a.name for a in node.names}
            else:
                continue
            bad = sorted(n for n in names if n.split(".")[-1] == "config_loading" or n.split(".")[0] == "yaml")
            bad = [] if id(node) in allowed else bad
            assert not bad, f"{_rel(p)} line {node.lineno} imports {bad} (a law is built from a gains object; from_config reads YAML)"
    code = "import sys, mavastsm.control\nprint(any(m in sys.modules for m in ('mavastsm.config_loading', 'yaml')))"
    import subprocess
    import sys

    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "False"


def test_the_import_scanner_sees_relative_imports():
    """The rules above are only as good as the scanner: it must resolve `from ..bridge import x` in a subpackage."""
    names = _imports(ROOT / "mavastsm" / "bench" / "bridge_runner.py")
    assert "mavastsm.bridge" in names and "mavastsm.telemetry" in names
    assert "mavastsm.bridge.link.mavlink_link" in _imports(ROOT / "mavastsm" / "bridge" / "bridge_api.py")


def test_help_imports_no_subcommand_module():
    """The CLI's promise (lazy subcommands): `mavastsm --help` loads neither the subcommands nor pymavlink, numpy or
    rich (it imported 53 package modules and took 0.41 s on an idle machine; now about 0.04 s)."""
    import subprocess
    import sys

    code = ("import sys\nfrom mavastsm.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(','.join(sorted(m for m in sys.modules if m.split('.')[0] in ('pymavlink', 'numpy', 'rich', 'mavastsm', 'mavastsm_sim'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip().splitlines()[-1]
    assert set(out.split(",")) <= {"mavastsm", "mavastsm.cli", "mavastsm.errors"}, out


CLASS_LINES_MAX = 400  # the house issue's floor: a class with one job fits in this
FUNCTION_LINES_MAX = 80


def test_no_class_over_400_lines_and_no_function_over_80_in_the_package_or_the_sim():
    """Measured with ``ast`` (first line of the ``def``/``class`` to its last line, docstring included)."""
    too_long = []
    for p in PACKAGE_FILES:
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            limit = (CLASS_LINES_MAX if isinstance(node, ast.ClassDef)
                     else FUNCTION_LINES_MAX if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) else None)
            if limit is not None and (lines := node.end_lineno - node.lineno + 1) > limit:
                too_long.append(f"{_rel(p)}:{node.lineno} {node.name} {lines} lines (at most {limit})")
    assert not too_long, "\n".join(too_long)
