"""Argument types shared by the commands: bad values fail in argparse with one clear line."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from tqdm import tqdm

from embodied_envs.cluster import RAY_LOCAL
from embodied_envs.config import MAX_IMAGE_SIDE, MAX_SEED, ConfigError, load_config
from embodied_envs.layout.sets import LayoutSet, spec_name
from embodied_envs.paths import default_layout


def _parse(text: str, convert, what: str):
    try:
        return convert(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None


def positive_int(text: str) -> int:
    """An integer >= 1."""
    value = _parse(text, int, "an integer")
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} is not a positive integer (>= 1)")
    return value


def seed_int(text: str) -> int:
    """A seed: an integer in [0, MAX_SEED] (ManiSkill's episode seeds)."""
    value = _parse(text, int, "an integer seed")
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"seed {value} is outside [0, {MAX_SEED}]")
    return value


def check_seed_span(first: int, count: int, what: str) -> None:
    """Every seed a command will use, ``first .. first + count - 1``, is a valid seed."""
    last = first + count - 1
    if last > MAX_SEED:
        raise SystemExit(
            f"error: --seed {first} with {count} {what} reaches seed {last}, over {MAX_SEED}. "
            f"Fix: --seed {MAX_SEED - count + 1} or lower"
        )


def image_side(text: str) -> int:
    """An image side in pixels, 1..MAX_IMAGE_SIDE."""
    value = positive_int(text)
    if value > MAX_IMAGE_SIDE:
        raise argparse.ArgumentTypeError(f"{value} pixels is over the {MAX_IMAGE_SIDE} limit")
    return value


def unit_float(text: str) -> float:
    """A finite number in [0, 1] (a colour channel)."""
    value = _parse(text, float, "a number")
    if not 0.0 <= value <= 1.0:  # NaN fails too
        raise argparse.ArgumentTypeError(f"{text} is not in [0, 1]")
    return value


def writable_dir(path):
    """An output folder that exists or can be made, and can be written: checked before any
    long work, so a bad ``--out`` costs one line, not a traceback after minutes."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise SystemExit(f"error: --out {path} is a file, not a folder. Fix: choose a folder.")
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise SystemExit(
            f"error: --out {path} cannot be written ({e.strerror}). Fix: choose a writable folder."
        ) from None
    return path


DEBUG_ENV = "EMBODIED_ENVS_DEBUG"  # set to 1: tracebacks instead of one-line errors


def failure_line(what: str, error: Exception) -> str:
    """One line for an error raised where the user's input met the simulator (a worker's env,
    a policy): its type and message, and how to see the traceback. Re-raised under
    ``EMBODIED_ENVS_DEBUG=1``."""
    if os.environ.get(DEBUG_ENV):
        raise error
    text = " ".join(str(error).split())
    return f"error: {what}: {type(error).__name__}: {text} (set {DEBUG_ENV}=1 for the traceback)"


def checked_layouts(specs: list[str] | None) -> list[tuple[str, list[Path]]]:
    """The command's ``--layout`` values (default: the shipped layout) as ``(name, files)``: a
    layout file, or a folder or glob naming a layout set (its files, absolute). Every layout
    and asset pool member is loaded and checked: bad input fails here, before any simulation.

    Raises:
        embodied_envs.layout.LayoutError
    """
    out = []
    for spec in specs or [str(default_layout())]:
        out.append((spec_name(spec), LayoutSet.load(spec).files))
    return out


def layout_value(files: list[Path]) -> str | tuple[str, ...]:
    """A ``checked_layouts`` entry's files as a plan holds them: one path, or a set's tuple."""
    return str(files[0]) if len(files) == 1 else tuple(str(f) for f in files)


LAYOUT_HELP = "layout file(s); a folder or glob is a layout set (each episode draws its layout)"


def note_workers(workers: int) -> None:
    if workers > (os.cpu_count() or 1):
        print(f"note: --workers {workers} is more than this machine's {os.cpu_count()} cores")


def add_ray_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--ray",
        nargs="?",
        const=RAY_LOCAL,
        default=None,
        metavar="ADDRESS",
        help="run the episodes as Ray tasks (docs/scaling.md): without a value on a Ray of this "
        "machine started for the command (or the cluster RAY_ADDRESS names); auto or host:port: "
        "a running cluster. --workers then caps the episodes running at once (default: the "
        "cluster's CPUs); an interrupted run resumes when run again with the same --out",
    )


def ran_on(workers: int, nodes: int) -> str:
    """Where a Ray run's episodes ran, in words (after a command's result line)."""
    return f", {workers} Ray worker{'s' * (workers != 1)} on {nodes} node{'s' * (nodes != 1)}"


class EpisodeBar:
    """One progress bar over a command's episodes, with the successes so far; called with
    each episode as it ends."""

    def __init__(self, total: int, desc: str):
        self.bar = tqdm(total=total, desc=desc, unit="episode")
        self.successes = 0

    def __call__(self, episode) -> None:
        self.successes += bool(episode.success)
        self.bar.set_postfix_str(f"success {self.successes}/{self.bar.n + 1}", refresh=False)
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        type=Path,
        action="append",
        help="YAML/JSON file of PickEmbodiedGen-v1 keywords; repeat to merge in order (later "
        "files win); flags win over files",
    )


def env_config(paths: list[Path] | None, owned: dict[str, str]) -> dict:
    """The env keywords of ``--config`` files, merged in order. A key the command sets itself
    is refused, naming the flag (or the reason) that sets it.

    Raises:
        embodied_envs.config.ConfigError
    """
    # the env class (torch, SAPIEN) only for commands that run it, not for --help
    from embodied_envs.envs.pick_embodiedgen import PickEmbodiedGenEnv

    config = load_config(paths, PickEmbodiedGenEnv.keywords(), PickEmbodiedGenEnv.check_keyword)
    taken = sorted(set(config) & set(owned))
    if taken:
        key = taken[0]
        raise ConfigError(
            f"{', '.join(map(str, paths))}: {key} is set by this command ({owned[key]}); "
            "remove it from the config file"
        )
    return config


CAMERA_OBS_MODES = ("rgb", "rgbd", "depth", "pointcloud", "rgb+depth+segmentation", "sensor_data")
CAMERA_SIZE = 64  # px, the sensor camera's side for camera observations (the visual recipe's)
ROBOT_VISUAL_FACES = 500  # triangles per robot visual mesh part for camera observations
# env keywords the camera flags set: a --config file may not set them
CAMERA_KEYS = {
    "hybrid_obs": "--hybrid-obs",
    "rooms": "--rooms",
    "sensor_configs": "--camera-size",
    "robot_visual_faces": "--robot-visual-faces",
}


def add_camera_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags of what a policy's camera sees: ``--hybrid-obs``, ``--rooms``,
    ``--camera-size``, ``--robot-visual-faces`` (the same in ``collect`` and ``eval``, so a
    visual policy is evaluated on the frames it was trained on)."""
    parser.add_argument("--hybrid-obs", action="store_true", help="sensor RGB over the splat room")
    parser.add_argument(
        "--rooms",
        nargs="+",
        default=None,
        help="with --hybrid-obs: the room pool each episode draws its splat background from, "
        "by its seed: 'shipped' (the layout's own room and the three of data/rooms), room "
        "folders (each with a gs_model.ply), a folder of them or a glob (default: the "
        "layout's own room)",
    )
    parser.add_argument(
        "--camera-size",
        type=image_side,
        default=CAMERA_SIZE,
        help=f"with a camera --obs-mode: the sensor camera's width and height in px (default "
        f"{CAMERA_SIZE}; ManiSkill's is 128)",
    )
    parser.add_argument(
        "--robot-visual-faces",
        type=int,
        default=ROBOT_VISUAL_FACES,
        help="with a camera --obs-mode: the robot's visual mesh parts decimated to at most this "
        "many triangles (CPU rendering's cost follows the triangles; 0: as shipped; default "
        f"{ROBOT_VISUAL_FACES})",
    )


def camera_env_kwargs(args) -> dict:
    """The env keywords of the camera flags (none for observations without a camera, where
    only ``--hybrid-obs`` would matter and is refused)."""
    if args.obs_mode not in CAMERA_OBS_MODES:
        if args.hybrid_obs or args.rooms:
            raise SystemExit(
                f"error: --hybrid-obs and --rooms composite camera frames; --obs-mode "
                f"{args.obs_mode} has none. Fix: --obs-mode rgb (or another camera mode)"
            )
        return {}
    if args.rooms and not args.hybrid_obs:
        raise SystemExit(
            "error: --rooms are splat backgrounds for --hybrid-obs. Fix: add --hybrid-obs"
        )
    kwargs: dict = dict(sensor_configs=dict(width=args.camera_size, height=args.camera_size))
    if args.robot_visual_faces:
        kwargs["robot_visual_faces"] = args.robot_visual_faces
    if args.hybrid_obs:
        kwargs["hybrid_obs"] = True
    if args.rooms:
        # the shipped pool by name (portable datasets); folders and globs as absolute paths
        kwargs["rooms"] = [r if r == "shipped" else str(Path(r).resolve()) for r in args.rooms]
        check_rooms(kwargs["rooms"])
    # the env's own checks, before any worker starts (one line, as a config file's values)
    from embodied_envs.envs.pick_embodiedgen import PickEmbodiedGenEnv  # torch: when it runs

    for name, value in kwargs.items():
        try:
            PickEmbodiedGenEnv.check_keyword(name, value)
        except ValueError as e:
            flag = CAMERA_KEYS.get(name, name)
            raise SystemExit(f"error: {flag}: {e}") from None
    return kwargs


def check_rooms(rooms: list[str]) -> None:
    """Every room of the pool a readable 3DGS PLY, before any worker starts; else one line."""
    # read when the command runs: `--help` stays without the splat and room modules
    from embodied_envs.layout.rooms import ROOM_FILE, RoomError, resolve_rooms
    from embodied_envs.splat import SplatFileError, check_ply

    try:
        for room in resolve_rooms(rooms):
            check_ply(room / ROOM_FILE)
    except (RoomError, SplatFileError) as e:
        raise SystemExit(f"error: --rooms: {e}") from None
