import json
import os
import subprocess
import sys

import imageio_ffmpeg
import numpy as np
import pytest
from conftest import DEFAULT_LAYOUT, LAYOUTS, ROOT, make_unreadable, snapshot
from PIL import Image

from embodied_envs.cli.main import main


def test_validate_ok_and_broken(tmp_path, scene_copy, capsys):
    shipped = sorted((ROOT / "embodied_envs" / "data" / "layouts").glob("*.json"))  # task ones too
    assert main(["layout", "validate", *map(str, shipped)]) == 0
    out = capsys.readouterr().out
    assert "place_box.json  task: place [can] on storage_box" in out
    assert "move_left.json  task: move [can] left" in out
    assert "place_two.json  task: place [can1, can2] on tray" in out
    assert "default.json  task: pick [can]" in out
    broken = scene_copy / "layouts" / "default.json"
    data = json.loads(broken.read_text())
    data["position"]["can"] = data["position"]["can"][:6]
    data["assets"]["mug"] = "../assets/nope"
    broken.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["layout", "validate", str(broken)]) == 1
    out = capsys.readouterr().out
    assert 'position["can"] has 6 numbers, expected 7' in out
    assert 'assets["mug"] folder ../assets/nope does not exist' in out


def _reserved_name(scene, monkeypatch):
    layout = scene / "layouts" / "default.json"
    layout.write_text(layout.read_text().replace('"mug"', '"goal_site"'))
    return ['node name "goal_site" is reserved', 'Fix: rename the node (e.g. "goal_site_1")']


def _link_loop(scene, monkeypatch):
    os.symlink("loop", scene / "assets" / "mug" / "loop")
    return ['assets["mug"]: ', f"{scene / 'assets' / 'mug' / 'loop'}: a symbolic link loop",
            "Fix: point the link at a real file or folder, or remove it."]  # fmt: skip


def _unreadable(scene, monkeypatch):
    urdf = scene / "assets" / "mug" / "mug.urdf"
    make_unreadable(urdf, monkeypatch)
    return ['assets["mug"]: ', f"{urdf}: the file cannot be read", "Fix: make it readable"]


@pytest.mark.parametrize("breaks", [_reserved_name, _link_loop, _unreadable])
def test_validate_refuses_reserved_names_link_loops_and_unreadable_files_in_one_line(
    scene_copy, capsys, monkeypatch, breaks
):
    words = breaks(scene_copy, monkeypatch)
    layout = scene_copy / "layouts" / "default.json"
    assert main(["layout", "validate", str(layout)]) == 1
    out = capsys.readouterr().out
    assert out.splitlines()[0] == f"FAIL {layout}" and len(out.splitlines()) == 2, out
    assert out.splitlines()[1].startswith(f"  - {layout}: "), out
    for word in words:
        assert word in out, out


def test_generate_writes_variants_with_rewritten_asset_paths(tmp_path, scene_copy):
    src = scene_copy / "layouts" / "default.json"
    before = snapshot(scene_copy)
    out = tmp_path.parent / (tmp_path.name + "_gen")
    assert (
        main(
            [
                "layout",
                "generate",
                str(src),
                "--num",
                "4",
                "--seed",
                "10",
                "--out",
                str(out),
                "--workers",
                "2",
            ]
        )
        == 0
    )
    files = sorted(out.glob("*.json"))
    assert len(files) == 4
    from embodied_envs.layout import load_layout

    layouts = [load_layout(f) for f in files]  # asset paths resolve from the new folder
    assert layouts[0].asset_dir("can") == (scene_copy / "assets" / "can").resolve()
    assert len({json.dumps(la.position["can"]) for la in layouts}) == 4
    assert snapshot(scene_copy) == before


def test_preview_png(tmp_path):
    out = tmp_path / "p.png"
    assert main(["layout", "preview", str(LAYOUTS[0]), "--out", str(out), "--size", "300"]) == 0
    img = np.asarray(Image.open(out))
    assert img.shape == (300, 300, 3)
    assert (np.abs(img.astype(int) - [215, 235, 215]).sum(-1) < 10).mean() > 0.05  # reach band


def test_demo_writes_video_and_summary(tmp_path):
    out = tmp_path / "demo"
    cmd = [
        sys.executable,
        "-m",
        "embodied_envs.cli.main",
        "demo",
        "--out",
        str(out),
        "--frame-every",
        "5",
        "--image-hw",
        "64",
        "96",
    ]
    subprocess.run(cmd, check=True, capture_output=True, timeout=600)
    summary = json.loads((out / "summary.json").read_text())
    ep = summary["episodes"][0]
    env0 = ep["envs"][0]
    assert env0["success"] is True and env0["plan_failures"] == [] and env0["robot"] == "panda"
    reader = imageio_ffmpeg.read_frames(str(out / "episode_000.mp4"))
    meta = next(reader)
    frames = [np.frombuffer(f, np.uint8).reshape(64, 96, 3) for f in reader]
    assert meta["size"] == (96, 64)
    assert len(frames) == ep["frames"] == env0["steps"] // 5 + 2
    assert frames[-1].std() > 5  # a real picture, not a blank frame


def test_demo_films_the_so100_on_its_layout_and_records_the_robot(tmp_path):
    """Another arm than the Panda: the layout's relation.robot (so100) is loaded, filmed over
    the splat (the default hybrid mode) and named in the summary (README's command: seed 10,
    which the expert carries out on the file's poses, seen from the arm's side)."""
    out = tmp_path / "demo"
    cmd = [sys.executable, "-m", "embodied_envs.cli.main", "demo", "--layout",
           str(ROOT / "layouts" / "so100_block.json"), "--seed", "10", "--out", str(out),
           "--camera-eye", "-0.1", "-0.25", "1.0", "--camera-target", "-0.3", "0.12", "0.82",
           "--frame-every", "10", "--image-hw", "48", "64"]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["render_mode"] == "hybrid" and summary["seed"] == 10
    (ep,) = summary["episodes"]
    (env0,) = ep["envs"]
    assert env0["robot"] == "so100" and env0["seed"] == 10
    assert isinstance(env0["success"], bool) and ep["success_rate"] == float(env0["success"])
    assert f"success {int(env0['success'])}/1" in res.stdout
    reader = imageio_ffmpeg.read_frames(str(out / "episode_000.mp4"))
    assert next(reader)["size"] == (64, 48)
    frames = [np.frombuffer(f, np.uint8).reshape(48, 64, 3) for f in reader]
    assert len(frames) == ep["frames"] == env0["steps"] // 10 + 2
    assert np.abs(frames[-1].astype(int) - frames[0]).mean() > 2  # the arm moved in view (4.2)


def test_splat_render_writes_colour_and_16_bit_depth(tmp_path, capsys):
    from conftest import ROOT

    ply = ROOT / "assets" / "background" / "gs_model.ply"
    png, depth_png = tmp_path / "room.png", tmp_path / "room_depth.png"
    # from the room's centre (Y-up file), looking at a wall 2.5 m away along +x
    args = ["splat", "render", str(ply), "--eye", "0", "1.3", "0", "--target", "1", "1.3", "0"]
    args += ["--up", "0", "1", "0", "--width", "64", "--height", "48", "--fovy", "40"]
    assert main([*args, "--out", str(png), "--depth-out", str(depth_png)]) == 0
    rgb = np.asarray(Image.open(png))
    assert rgb.shape == (48, 64, 3) and rgb.mean() > 100, "a lit wall fills the view"
    depth = np.asarray(Image.open(depth_png))
    assert depth.dtype == np.uint16 and depth.shape == (48, 64)
    # the +x wall's inner face is at x = 2.5 m: centre pixels read ~2500 mm
    assert abs(int(np.median(depth[20:28, 28:36])) - 2500) < 30

    capsys.readouterr()
    assert main(["splat", "render", str(tmp_path / "nope.ply"), *args[3:], "--out", str(png)]) == 1
    assert "nope.ply: file does not exist" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, words",
    [
        (["demo", "--frame-every", "0"], "0 is not a positive integer"),
        (["demo", "--episodes", "-1"], "-1 is not a positive integer"),
        (["layout", "generate", "LAYOUT", "--num", "2", "--seed", "-5", "--out", "o"], "seed -5"),
        (["layout", "preview", "LAYOUT", "--out", "p.png", "--size", "0"], "positive integer"),
        (["splat", "render", "PLY", "--eye", "0", "1", "0", "--target", "1", "1", "0",
          "--background", "nan", "2", "-1", "--out", "x.png"], "nan is not in [0, 1]"),
        (["splat", "render", "PLY", "--eye", "0", "1", "0", "--target", "1", "1", "0",
          "--width", "100000", "--out", "x.png"], "over the 8192 limit"),
    ],
)  # fmt: skip
def test_bad_arguments_are_one_line_before_any_work(tmp_path, capsys, args, words):
    ply = ROOT / "assets" / "background" / "gs_model.ply"
    args = [str(DEFAULT_LAYOUT) if a == "LAYOUT" else str(ply) if a == "PLY" else a for a in args]
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_unwritable_out_is_one_line(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(SystemExit) as e:
        main(["layout", "generate", str(DEFAULT_LAYOUT), "--num", "1", "--out", str(blocker)])
    assert "is a file, not a folder" in str(e.value.code)
    assert blocker.read_text() == "x"


def test_ctrl_c_prints_what_was_kept_and_the_command_that_resumes(tmp_path, monkeypatch, capsys):
    from embodied_envs.cli import collect

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(collect, "cmd_collect", interrupted)
    argv = ["collect", "--num", "4", "--out", str(tmp_path), "--ray", "auto"]
    assert main(argv) == 130
    command = f"embodied-envs {' '.join(argv)}"
    assert (
        capsys.readouterr().err
        == f"interrupted: nothing kept to resume; to start again: {command}\n"
    )
    for seed in ("000700", "000701", ".000702.tmp"):  # a folder being written is not kept
        (tmp_path / ".resume-default" / seed).mkdir(parents=True)
    assert main(argv) == 130
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"(2 in {tmp_path / '.resume-default'})" in err
    assert err.endswith(f"to resume them: {command}\n")
