import numpy as np
import pytest
import torch
from splat_helpers import random_splat

from embodied_envs.splat import SplatFileError, read_ply, write_ply
from embodied_envs.splat.ply import REQUIRED

PROPS = list(REQUIRED)  # x y z f_dc_0..2 opacity scale_0..2 rot_0..3 (INRIA layout)


def write_raw(
    path, names, rows, fmt="binary_little_endian", element="vertex", count=None, types=None
):
    """An independent PLY writer: any property order and types."""
    types = types or ["float"] * len(names)
    np_types = {"float": "<f4", "double": "<f8", "uchar": "u1"}
    dtype = np.dtype([(n, np_types[t]) for n, t in zip(names, types, strict=True)])
    table = np.zeros(len(rows), dtype=dtype)
    for i, n in enumerate(names):
        table[n] = rows[:, i]
    n = len(rows) if count is None else count
    header = ["ply", f"format {fmt} 1.0", f"element {element} {n}"]
    header += [f"property {t} {n}" for n, t in zip(names, types, strict=True)]
    path.write_bytes(("\n".join([*header, "end_header"]) + "\n").encode() + table.tobytes())
    return path


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("normals", [False, True])
def test_round_trip_is_lossless(tmp_path, degree, normals):
    s = random_splat(degree, n=50, sh_degree=degree, normals=normals)
    back = read_ply(write_ply(s, tmp_path / "s.ply"))
    assert back.sh_degree == degree
    for f in ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh"):
        assert torch.equal(getattr(back, f), getattr(s, f)), f
    assert (back.normals is None) == (not normals)
    if normals:
        assert torch.equal(back.normals, s.normals)


def test_reads_inria_layout_with_sh_channel_major_and_other_types(tmp_path):
    # INRIA order: x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_* rot_*
    rest = [f"f_rest_{i}" for i in range(45)]
    names = ["x", "y", "z", "nx", "ny", "nz", *(f"f_dc_{i}" for i in range(3)), *rest]
    names += ["opacity", *(f"scale_{i}" for i in range(3)), *(f"rot_{i}" for i in range(4))]
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(7, len(names)))
    types = ["double" if n == "opacity" else "float" for n in names]
    s = read_ply(write_raw(tmp_path / "inria.ply", names, rows, types=types))
    assert len(s) == 7 and s.sh_degree == 3
    col = {n: i for i, n in enumerate(names)}
    # coefficient k >= 1 of channel c is f_rest_{c * 15 + k - 1}
    assert s.sh[3, 4, 2].item() == pytest.approx(rows[3, col["f_rest_33"]], abs=1e-6)
    assert s.sh[3, 0, 1].item() == pytest.approx(rows[3, col["f_dc_1"]], abs=1e-6)
    assert s.opacity_logits[5].item() == pytest.approx(rows[5, col["opacity"]], abs=1e-6)
    assert s.quats_wxyz[2, 0].item() == pytest.approx(rows[2, col["rot_0"]], abs=1e-6)
    assert s.normals is not None


def test_activations(tmp_path):
    rows = np.array([[0, 0, 0, 0.1, 0.2, 0.3, 0.0, np.log(0.5), 0, 0, 2, 0, 0, 0]], float)
    s = read_ply(write_raw(tmp_path / "a.ply", PROPS, rows))
    assert s.opacities.item() == pytest.approx(0.5)
    assert s.scales[0].tolist() == pytest.approx([0.5, 1.0, 1.0])
    assert s.unit_quats_wxyz[0].tolist() == pytest.approx([1, 0, 0, 0])


@pytest.mark.parametrize(
    "case, words",
    [
        ("missing_opacity", ["lacks", "opacity"]),
        ("truncated", ["truncated", "10 vertices"]),
        ("no_vertex", ["no 'vertex' element"]),
        ("ascii", ["binary_little_endian"]),
        ("bad_rest", ["f_rest", "0, 9, 24 or 45"]),
        ("not_ply", ["not a PLY"]),
        ("missing_file", ["does not exist"]),
        ("nan", ["NaN", "vertex 3"]),
        ("inf_opacity", ["infinite", "vertex 2"]),
    ],
)
def test_malformed_files_are_rejected_with_the_file_and_the_fix(tmp_path, case, words):
    rows = np.ones((10, len(PROPS)))
    path = tmp_path / f"{case}.ply"
    if case == "missing_opacity":
        keep = [i for i, n in enumerate(PROPS) if n != "opacity"]
        write_raw(path, [PROPS[i] for i in keep], rows[:, keep])
    elif case == "truncated":
        write_raw(path, PROPS, rows)
        path.write_bytes(path.read_bytes()[:-30])
    elif case == "no_vertex":
        write_raw(path, PROPS, rows, element="face")
    elif case == "ascii":
        write_raw(path, PROPS, rows, fmt="ascii")
    elif case == "bad_rest":
        names = PROPS + [f"f_rest_{i}" for i in range(10)]
        write_raw(path, names, np.ones((10, len(names))))
    elif case == "not_ply":
        path.write_text("solid cube\nendsolid\n")
    elif case == "nan":
        rows[3, 0] = np.nan
        write_raw(path, PROPS, rows)
    elif case == "inf_opacity":
        rows[2, PROPS.index("opacity")] = np.inf
        write_raw(path, PROPS, rows)
    with pytest.raises(SplatFileError) as e:
        read_ply(path)
    msg = str(e.value)
    assert str(path) in msg and "Fix:" in msg
    for w in words:
        assert w in msg, msg


def test_an_inria_file_renders_like_the_reference_from_its_raw_values(tmp_path):
    """End to end: independent INRIA-order file -> read_ply -> render, against the reference
    fed with activations computed here from the raw rows (sigmoid, exp, normalise, SH)."""
    from reference import render_reference

    from embodied_envs.splat import PinholeCamera, render
    from embodied_envs.splat.sh import SH_C0

    rng = np.random.default_rng(3)
    n = 150
    rest = [f"f_rest_{i}" for i in range(45)]
    names = ["x", "y", "z", "nx", "ny", "nz", *(f"f_dc_{i}" for i in range(3)), *rest]
    names += ["opacity", *(f"scale_{i}" for i in range(3)), *(f"rot_{i}" for i in range(4))]
    col = {c: i for i, c in enumerate(names)}
    rows = np.zeros((n, len(names)))
    rows[:, 0:3] = rng.uniform(-1, 1, (n, 3))
    rows[:, [col[f"f_dc_{i}"] for i in range(3)]] = rng.normal(0, 1, (n, 3))
    rows[:, [col[r] for r in rest]] = rng.normal(0, 0.1, (n, 45))
    rows[:, col["opacity"]] = rng.normal(1, 1.5, n)
    rows[:, [col[f"scale_{i}"] for i in range(3)]] = np.log(rng.uniform(0.02, 0.2, (n, 3)))
    rows[:, [col[f"rot_{i}"] for i in range(4)]] = rng.normal(size=(n, 4))
    rows = rows.astype(np.float32).astype(np.float64)
    splat = read_ply(write_raw(tmp_path / "point_cloud.ply", names, rows))
    cam = PinholeCamera.look_at((0.4, -2.6, 0.9), (0, 0, 0), width=40, height=32)
    image = render(splat, cam, backend="torch")

    # view-dependent colour of all 16 bands (3DGS constants and signs), evaluated here
    eye = cam.center
    d = rows[:, :3] - eye
    x, y, z = (d / np.linalg.norm(d, axis=1, keepdims=True)).T
    basis = np.stack(
        [
            np.full(n, SH_C0),
            -0.4886025119029199 * y,
            0.4886025119029199 * z,
            -0.4886025119029199 * x,
            1.0925484305920792 * x * y,
            -1.0925484305920792 * y * z,
            0.31539156525252005 * (2 * z * z - x * x - y * y),
            -1.0925484305920792 * x * z,
            0.5462742152960396 * (x * x - y * y),
            -0.5900435899266435 * y * (3 * x * x - y * y),
            2.890611442640554 * x * y * z,
            -0.4570457994644658 * y * (4 * z * z - x * x - y * y),
            0.3731763325901154 * z * (2 * z * z - 3 * x * x - 3 * y * y),
            -0.4570457994644658 * x * (4 * z * z - x * x - y * y),
            1.445305721320277 * z * (x * x - y * y),
            -0.5900435899266435 * x * (x * x - 3 * y * y),
        ],
        axis=1,
    )
    coeffs = np.zeros((n, 16, 3))
    for c in range(3):
        coeffs[:, 0, c] = rows[:, col[f"f_dc_{c}"]]
        coeffs[:, 1:, c] = rows[:, [col[f"f_rest_{c * 15 + k}"] for k in range(15)]]
    colors = np.clip(0.5 + np.einsum("nk,nkc->nc", basis, coeffs), 0, 1)
    quats = rows[:, [col[f"rot_{i}"] for i in range(4)]]
    rgb, alpha, depth = render_reference(
        rows[:, :3],
        quats / np.linalg.norm(quats, axis=1, keepdims=True),
        np.exp(rows[:, [col[f"scale_{i}"] for i in range(3)]]),
        1 / (1 + np.exp(-rows[:, col["opacity"]])),
        colors,
        cam.world_to_cam,
        cam.fx,
        cam.fy,
        cam.cx,
        cam.cy,
        cam.width,
        cam.height,
    )
    assert alpha.mean() > 0.2
    assert (np.abs(image.rgb.numpy() - rgb) > 2 / 255).mean() <= 0.01
    assert (np.abs(image.alpha.numpy() - alpha) > 2 / 255).mean() <= 0.01


def _rows(n):
    rows = np.zeros((n, len(PROPS)), np.float32)
    rows[:, PROPS.index("rot_0")] = 1.0
    return rows


@pytest.mark.parametrize(
    "change, words",
    [
        ("empty", "it holds 0 Gaussians"),
        ("bad_count", "has count '-3', not a non-negative integer"),
        ("huge_scale", "have a scale over 1000 m (first: vertex 2"),
        ("zero_quaternion", "all-zero rotation quaternion (first: vertex 1"),
        ("far_mean", "lie over 10000 m from the origin (first: vertex 3"),
    ],
)
def test_splats_that_parse_but_cannot_render_are_refused(tmp_path, change, words):
    rows = _rows(4)
    kw = {}
    if change == "empty":
        rows = rows[:0]
        kw["count"] = "0"
    elif change == "bad_count":
        kw["count"] = "-3"
    elif change == "huge_scale":
        rows[2, PROPS.index("scale_1")] = 50.0  # exp(50) m
    elif change == "zero_quaternion":
        rows[1, PROPS.index("rot_0")] = 0.0
    elif change == "far_mean":
        rows[3, PROPS.index("y")] = 1e30  # renders nothing: a black room
    path = write_raw(tmp_path / "bad.ply", PROPS, rows, **kw)
    with pytest.raises(SplatFileError) as e:
        read_ply(path)
    assert words in str(e.value) and str(path) in str(e.value)


def test_checking_a_large_splat_reads_it_in_bounded_memory(tmp_path):
    """``check_ply`` (layout validate) reads the vertex element chunk by chunk: its peak
    allocation (NumPy's, traced) stays well under the file's size, and a bad value in the last
    chunk is found with its true vertex number."""
    import tracemalloc

    from embodied_envs.splat.ply import check_ply

    n = 2_400_000
    rows = _rows(n)
    rows[n - 5, PROPS.index("x")] = float("nan")
    path = write_raw(tmp_path / "large.ply", PROPS, rows)
    del rows
    size = path.stat().st_size
    tracemalloc.start()
    try:
        with pytest.raises(SplatFileError) as e:
            check_ply(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert f"first: vertex {n - 5}" in str(e.value)
    assert peak < 0.5 * size, f"peak allocation {peak:,} bytes for a {size:,}-byte file"
