"""Every generator of shipped data in tools/make/ writes, into a temporary folder, what is
shipped, byte for byte: the assets and the room's splat (make_assets.py, mesh_to_splat.py), the
layouts (make_layouts.py), the grasp zoo (make_grasp_zoo.py), the upright-mover layouts
(make_upright.py) and the bad-input corpus (make_bad_inputs.py). A failure names the files
that differ and the script that writes them."""

import importlib.util
import sys

import pytest
from conftest import DATA, ROOT, snapshot

TOOLS = ROOT / "tools" / "make"
SHIPPED = {
    "assets": DATA / "assets",
    "layouts": DATA / "layouts",
    "zoo": ROOT / "tests" / "data" / "zoo",
    "upright": ROOT / "tests" / "data" / "upright",
    "bad_inputs": ROOT / "tests" / "data" / "bad_inputs",
}


@pytest.fixture(scope="module")
def tool():
    """A script of tools/make/ as a module, by its file name (tools/make/ on the path, as when
    the scripts run: they import each other); every module loaded is unloaded afterwards."""
    before = set(sys.modules)
    sys.path.insert(0, str(TOOLS))
    try:
        yield _load
    finally:
        sys.path.remove(str(TOOLS))
        for name in set(sys.modules) - before:
            if getattr(sys.modules[name], "__file__", "").startswith(str(TOOLS)):
                del sys.modules[name]


def _load(name: str):
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    module = sys.modules[name] = importlib.util.module_from_spec(spec)  # dataclasses need it
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module", autouse=True)
def shipped_untouched():
    """No generator writes into the shipped folders while it is tested."""
    before = {k: snapshot(v) for k, v in SHIPPED.items()}
    yield
    assert {k: snapshot(v) for k, v in SHIPPED.items()} == before


def files(folder) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def assert_same_files(written, shipped, script: str) -> None:
    got, want = files(written), files(shipped)
    assert sorted(got) == sorted(want), (
        f"{script} writes {sorted(set(got) - set(want))} and not {sorted(set(want) - set(got))}"
    )
    differ = sorted(k for k in want if got[k] != want[k])
    assert not differ, f"{script} does not reproduce {differ} of {shipped}"
    assert want, f"{shipped} holds no file"


def test_make_assets_and_mesh_to_splat_reproduce_the_shipped_assets(tmp_path, tool):
    out = tmp_path / "assets"
    tool("make_assets").main(["--out", str(out)])
    background = out / "background"
    tool("mesh_to_splat").main(
        [str(background / "mesh_model.ply"), "--out", str(background / "gs_model.ply")]
    )
    script = "tools/make/make_assets.py + tools/make/mesh_to_splat.py"
    assert_same_files(out, SHIPPED["assets"], script)


def test_make_layouts_reproduces_the_shipped_layouts(tmp_path, tool):
    tool("make_layouts").main(["--out", str(tmp_path)])
    assert_same_files(tmp_path, SHIPPED["layouts"], "tools/make/make_layouts.py")


def test_make_grasp_zoo_reproduces_the_shipped_zoo(tmp_path, tool):
    tool("make_grasp_zoo").main(["--out", str(tmp_path)])
    assert_same_files(tmp_path, SHIPPED["zoo"], "tools/make/make_grasp_zoo.py")


def test_make_upright_reproduces_the_shipped_upright_layouts(tmp_path, tool):
    tool("make_upright").main(["--out", str(tmp_path)])
    assert_same_files(tmp_path, SHIPPED["upright"], "tools/make/make_upright.py")


def test_make_bad_inputs_reproduces_the_shipped_corpus(tmp_path, tool):
    tool("make_bad_inputs").main(["--out", str(tmp_path / "bad_inputs")])
    script = "tools/make/make_bad_inputs.py"
    assert_same_files(tmp_path / "bad_inputs", SHIPPED["bad_inputs"], script)


def test_a_changed_file_is_named(tmp_path):
    """The comparison itself: a byte changed, a file missing, a file added."""
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.json").write_text("{}\n")
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "x.json").write_text("{} \n")
    with pytest.raises(AssertionError, match=r"does not reproduce \['x.json'\]"):
        assert_same_files(tmp_path / "a", tmp_path / "b", "s")
    (tmp_path / "b" / "y.json").write_text("")
    with pytest.raises(AssertionError, match=r"writes \[\] and not \['y.json'\]"):
        assert_same_files(tmp_path / "a", tmp_path / "b", "s")
