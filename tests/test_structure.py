"""The package's dependency direction: which subpackages each one pulls in, no import cycles,
function-local imports only where they keep a command free of the simulator (said in a
comment), and ManiSkill's private fields reached from one module only (``internals.py``)."""

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

PACKAGE = ROOT / "embodied_envs"
# importing embodied_envs registers the env id: every import pulls in registration
ALWAYS = {"registration"}
# what importing each part may pull in (the README's "Where things are": layout -> scene ->
# envs -> solvers -> pipelines -> cli, datasets beside solvers; splat, paths, workers and
# internals, ManiSkill's private fields, stand alone)
ALLOWED = {
    "paths": set(),
    "workers": set(),
    "internals": set(),
    "cluster": {"paths"},  # Ray: imported only where a run asks for it
    "registration": set(),
    "splat": set(),
    "robots": set(),
    "layout": {"paths", "robots"},
    "config": {"layout", "paths", "robots"},
    "scene": {"layout", "paths", "robots"},
    "envs": {"layout", "paths", "scene", "splat", "config", "robots", "internals"},
    # the expert records a control mode's actions as the converters compute them (solvers/modes.py)
    "solvers": {"layout", "paths", "robots", "datasets", "config", "internals"},
    "datasets": {"layout", "paths", "config", "robots", "internals"},
    "pipelines": {
        "layout", "paths", "scene", "splat", "config", "envs", "solvers", "workers", "robots",
        "datasets", "internals", "cluster",
    },
    "cli": {
        "layout", "paths", "splat", "config", "workers", "pipelines", "robots", "datasets",
        "internals", "cluster",
    },
}
HEAVY = ("torch", "sapien", "mani_skill")  # the simulator: not for --help or layout commands


def imported_by(part: str) -> tuple[set[str], set[str]]:
    code = (
        "import importlib, json, sys\n"
        f"importlib.import_module('embodied_envs.{part}')\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)  # fmt: skip
    modules = json.loads(out.stdout.strip().splitlines()[-1])
    parts = {m.split(".")[1] for m in modules if m.startswith("embodied_envs.")}
    heavy = {h for h in HEAVY if h in modules}
    return parts - {part} - ALWAYS, heavy


@pytest.mark.parametrize("part", sorted(ALLOWED))
def test_each_part_pulls_in_only_what_is_below_it(part):
    parts, heavy = imported_by(part)
    assert parts <= ALLOWED[part], f"{part} imports {sorted(parts - ALLOWED[part])}"
    if part in ("paths", "workers", "cluster", "registration", "splat", "robots", "layout",
                "config", "datasets", "internals"):  # fmt: skip
        assert not heavy, f"{part} imports {sorted(heavy)}"


def test_the_command_line_starts_without_the_simulator():
    _, heavy = imported_by("cli.main")
    assert not heavy, heavy


def test_placement_needs_torch_only_for_the_episode_sampler():
    """The placement room holds the per-episode sampler (torch arrays on a GPU), imported from
    its own module: ``place()`` and the layout commands run without torch."""
    _, heavy = imported_by("layout.placement")
    assert not heavy, heavy
    _, heavy = imported_by("layout.placement.episode")
    assert "torch" in heavy and "mani_skill" not in heavy, heavy


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def package_imports(source: str) -> set[str]:
    """The package's modules a module imports: at the top, inside functions (a deferred import
    is still a dependency) and in ``if TYPE_CHECKING`` blocks (a type-only import is one too:
    two modules that name each other's types are one module cut in two)."""
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module.startswith("embodied_envs"):
                for alias in node.names:  # `from pkg import module` imports the module
                    sub = f"{node.module}.{alias.name}"
                    where = ROOT / sub.replace(".", "/")
                    found.add(sub if where.with_suffix(".py").is_file() or where.is_dir()
                              else node.module)  # fmt: skip
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("embodied_envs")}
    return found


def import_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` (module -> the modules it imports) as ``[a, b, ..., a]``, or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(m: str, stack: list[str]) -> list[str] | None:
        state[m] = 1
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                return stack[stack.index(d) :] + [d]
            if d not in state and (cycle := visit(d, stack + [d])):
                return cycle
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (cycle := visit(m, [m])):
            return cycle
    return None


def test_no_import_cycles_between_modules():
    """No two modules of the package import each other, directly or round a longer circle, at
    the top, in a function or for type hints only (``solvers/grasp_types.py`` and
    ``solvers/solver_config.py`` hold the definitions two rooms share)."""
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {m: {d for d in package_imports(p.read_text()) if d in modules and d != m}
             for m, p in modules.items()}  # fmt: skip
    cycle = import_cycle(graph)
    assert cycle is None, f"import cycle: {' -> '.join(cycle)}"


def test_a_type_only_import_cycle_is_found():
    a = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from embodied_envs.b import B\n"
    assert package_imports(a) == {"embodied_envs.b"}
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert import_cycle(graph) == ["a", "b", "c", "a"]
    assert import_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def says_why(line: str) -> bool:
    """A comment with words beyond a linter's ``noqa`` code."""
    comment = line.partition("#")[2]
    words = re.sub(r"noqa(: *[A-Z]+[0-9]+(, *[A-Z]+[0-9]+)*)?", "", comment)
    return any(c.isalpha() for c in words)


def local_imports(path: Path):
    """``(line, text)`` of every import inside a function, with whether a comment explains
    it (on its line, or on a comment line right above the import block)."""
    lines = path.read_text().splitlines()
    tree = ast.parse(path.read_text())
    for fn in ast.walk(tree):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.Import | ast.ImportFrom):
                k = node.lineno - 1
                explained = says_why(lines[k])
                j = k - 1
                while (
                    not explained
                    and j >= 0
                    and lines[j].strip().startswith(("import ", "from ", "#", ")"))
                    or (j >= 0 and lines[j].strip() == "" and j == k - 1)
                ):
                    explained = lines[j].strip().startswith("#") and says_why(lines[j])
                    j -= 1
                yield node.lineno, lines[k].strip(), explained


def test_every_function_local_import_says_why():
    unexplained = [
        f"{p.relative_to(ROOT)}:{line}: {text}"
        for p in sorted(PACKAGE.rglob("*.py"))
        for line, text, explained in local_imports(p)
        if not explained
    ]
    assert not unexplained, "\n".join(unexplained)


MODULE_LINES = 500  # issue 33: no module of the package over this
ENV_FILE, ENV_FILE_LINES = PACKAGE / "envs" / "pick_embodiedgen.py", 300  # the env reads in one go


def test_no_module_is_over_its_size():
    """Issue 33's targets: every module <= 500 lines, the env file <= 300."""
    counts = {p: len(p.read_text().splitlines()) for p in sorted(PACKAGE.rglob("*.py"))}
    over = [f"{p.relative_to(ROOT)}: {n} lines (limit {MODULE_LINES})"
            for p, n in counts.items() if n > MODULE_LINES]  # fmt: skip
    if counts[ENV_FILE] > ENV_FILE_LINES:
        over.append(f"{ENV_FILE.relative_to(ROOT)}: {counts[ENV_FILE]} lines "
                    f"(limit {ENV_FILE_LINES} for the env file)")  # fmt: skip
    assert not over, "\n".join(over)


# the one module that reads ManiSkill's and SAPIEN's private fields (behind named functions)
PRIVATE_READER = PACKAGE / "internals.py"
# private attributes of other objects that the package may reach elsewhere, each with its reason
# (module, expression as ast.unparse writes it)
PRIVATE_ALLOWED = {
    # the standard library's documented exit without clean-up, for a forked worker process
    ("embodied_envs/workers.py", "os._exit"),
    # the same, replaced by one that raises in a policy's code (policy_code: not a lost worker)
    ("embodied_envs/pipelines/policies.py", "os._exit"),
    # ProcessPoolExecutor keeps no public list of its processes: a failed run stops them at once
    ("embodied_envs/workers.py", "pool._processes"),
}


def private_reaches(tree: ast.AST) -> list[tuple[int, str]]:
    """``(line, expression)`` of each reach into a private attribute (one leading underscore)
    of an object other than the code's own (``self``, ``cls``, ``super()``): ``x._name`` or
    ``getattr(x, "_name")`` / ``setattr`` / ``hasattr`` with a literal name."""

    def own(value: ast.AST) -> bool:
        return (isinstance(value, ast.Name) and value.id in ("self", "cls")) or (
            isinstance(value, ast.Call) and ast.unparse(value.func) == "super"
        )

    def private(name) -> bool:
        return isinstance(name, str) and name.startswith("_") and not name.startswith("__")

    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and private(node.attr) and not own(node.value):
            found.append((node.lineno, ast.unparse(node)))
        elif (
            isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
            and node.func.id in ("getattr", "setattr", "hasattr", "delattr")
            and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant)
            and private(node.args[1].value) and not own(node.args[0])
        ):  # fmt: skip
            found.append((node.lineno, ast.unparse(node)))
    return sorted(found)


def test_only_internals_reaches_private_fields_of_other_objects():
    """ManiSkill's private fields (``._objs``, ``._bodies``, ``._controller_configs``, a
    controller's ``._target_qpos``...) are read through ``embodied_envs/internals.py`` only: a
    ManiSkill release that renames one breaks that module alone."""
    reaches = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == PRIVATE_READER:
            continue
        rel = str(path.relative_to(ROOT))
        reaches += [f"{rel}:{line}: {expr}"
                    for line, expr in private_reaches(ast.parse(path.read_text()))
                    if (rel, expr) not in PRIVATE_ALLOWED]  # fmt: skip
    assert not reaches, (
        "private attributes of other objects reached outside embodied_envs/internals.py "
        "(add a named function there):\n" + "\n".join(reaches)
    )
    assert private_reaches(ast.parse(PRIVATE_READER.read_text()))


def test_a_reach_into_a_private_field_is_found():
    code = (
        "class A:\n"
        "    def f(self, actor, agent):\n"
        "        self._mine = super()._hook() + cls._x\n"
        "        q = actor._objs[0].pose\n"
        "        return getattr(agent, '_controller_configs'), agent.__dict__, hasattr(q, 'p')\n"
    )
    found = private_reaches(ast.parse(code))
    assert found == [(4, "actor._objs"), (5, "getattr(agent, '_controller_configs')")]
