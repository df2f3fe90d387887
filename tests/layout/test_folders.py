"""Asset folders walked before use (layout/folders.py): a symbolic link loop or an unreadable
file is one LayoutError naming the layout file, the node, the path and the fix."""

import os

import pytest
from conftest import make_unreadable, snapshot

from embodied_envs.layout import LayoutError, load_layout
from embodied_envs.layout.folders import MAX_FOLDER_ENTRIES, check_folder, resolve_path


def _refusal(scene_copy) -> str:
    layout = scene_copy / "layouts" / "default.json"
    before = snapshot(scene_copy / "layouts")
    with pytest.raises(LayoutError) as e:
        load_layout(layout)
    assert snapshot(scene_copy / "layouts") == before, "nothing is written"
    assert len(e.value.problems) == 1, e.value.problems
    msg = e.value.problems[0]
    assert msg.startswith(f'{layout}: assets["mug"]: '), msg
    return msg


def test_a_symbolic_link_loop_in_an_asset_folder_is_named(scene_copy):
    link = scene_copy / "assets" / "mug" / "mesh" / "old"
    os.symlink("old", link)  # unused by the URDF, but a walk of the folder would never end
    msg = _refusal(scene_copy)
    assert f"{link}: a symbolic link loop" in msg
    assert "Fix: point the link at a real file or folder, or remove it." in msg


def test_a_mesh_that_is_a_link_loop_is_named(scene_copy):
    mesh = scene_copy / "assets" / "mug" / "mesh" / "mug_collision.obj"
    mesh.unlink()
    os.symlink("mug_collision.obj", mesh)
    assert f"{mesh}: a symbolic link loop" in _refusal(scene_copy)


def test_an_asset_folder_that_is_a_link_loop_is_named_not_a_bare_runtime_error(scene_copy):
    """``Path.resolve`` raised a bare RuntimeError here."""
    os.symlink("mug_loop", scene_copy / "assets" / "mug_loop")
    layout = scene_copy / "layouts" / "default.json"
    layout.write_text(layout.read_text().replace('"../assets/mug"', '"../assets/mug_loop"'))
    msg = _refusal(scene_copy)
    assert "assets/mug_loop is a symbolic link loop" in msg and "Fix: point the link" in msg


def test_a_folder_link_back_to_its_own_folder_is_a_loop(scene_copy):
    link = scene_copy / "assets" / "mug" / "mesh" / "up"
    os.symlink("..", link)
    msg = _refusal(scene_copy)
    assert f"{link}: a symbolic link loop (it links to {scene_copy / 'assets' / 'mug'}" in msg


def test_an_unreadable_file_in_an_asset_folder_is_named(scene_copy, monkeypatch):
    mesh = scene_copy / "assets" / "mug" / "mesh" / "mug_collision.obj"
    make_unreadable(mesh, monkeypatch)
    msg = _refusal(scene_copy)
    assert f"{mesh}: the file cannot be read (Permission denied)" in msg
    assert "Fix: make it readable (chmod a+r)" in msg


def test_links_that_resolve_are_accepted_and_linked_folders_not_entered(tmp_path):
    (tmp_path / "mesh").mkdir()
    (tmp_path / "mesh" / "a.obj").write_text("v 0 0 0\n")
    os.symlink("a.obj", tmp_path / "mesh" / "b.obj")
    os.symlink("mesh", tmp_path / "alias")
    os.symlink("/", tmp_path / "mesh" / "elsewhere_deeper_than_allowed")  # holds tmp_path
    with pytest.raises(LayoutError, match="it links to /, a folder holding it"):
        check_folder(tmp_path)
    os.unlink(tmp_path / "mesh" / "elsewhere_deeper_than_allowed")
    os.symlink("/usr", tmp_path / "mesh" / "usr")  # a large folder outside: never walked
    os.symlink("missing", tmp_path / "dangling")  # named where a URDF uses it
    check_folder(tmp_path)
    assert resolve_path(tmp_path / "mesh" / "b.obj", "x") == tmp_path / "mesh" / "a.obj"


def test_a_folder_of_more_entries_than_an_asset_holds_is_refused(tmp_path):
    for i in range(MAX_FOLDER_ENTRIES + 1):
        (tmp_path / f"f{i}").mkdir()
    with pytest.raises(LayoutError, match=f"{tmp_path}: over 10,000 entries") as e:
        check_folder(tmp_path)
    assert "Fix: point the layout's assets entry at the asset's own folder" in str(e.value)
