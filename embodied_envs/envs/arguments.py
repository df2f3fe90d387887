"""Checks of the env's arguments: constructor keywords, ``reset`` seeds and options, actions.

Each check raises ``ValueError`` (or ``RuntimeError`` for a closed env) naming the argument,
what it got and what is accepted, before the simulator sees the value.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import warnings
from pathlib import Path

import numpy as np
import torch

from embodied_envs.config import MAX_SEED
from embodied_envs.layout.pose import QUAT_NORM_TOLERANCE


def dataclass_arg(cls, value, name: str):
    """A dataclass keyword given as the dataclass, a dict of its fields, or None (defaults)."""
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, dict):
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(value) - known)
        if unknown:
            raise ValueError(f"{name}: unknown keys {unknown}; known: {sorted(known)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in value.items()})
    raise ValueError(f"{name} must be a dict of {cls.__name__} fields, got {type(value).__name__}")


def check_flag(name: str, value) -> bool:
    """A boolean keyword: True or False only (a YAML ``"false"`` string would be true)."""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    raise ValueError(
        f"{name}={value!r} must be True or False (in a config file: true/false, not a string)"
    )


def check_quaternion(name: str, value) -> tuple[float, float, float, float]:
    """Four finite numbers (x, y, z, w) of unit norm within ``QUAT_NORM_TOLERANCE``."""
    try:
        q = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        q = ()
    norm = math.sqrt(sum(v * v for v in q)) if len(q) == 4 else float("nan")
    if len(q) != 4 or not all(map(math.isfinite, q)) or abs(norm - 1) > QUAT_NORM_TOLERANCE:
        raise ValueError(
            f"{name}={value!r} must be a unit quaternion (x, y, z, w) of 4 finite numbers, "
            f"|q| within {QUAT_NORM_TOLERANCE} of 1"
        )
    return q


# what ManiSkill 3.0.1's BaseEnv.reset reads from options (mani_skill/envs/sapien_env.py); it
# passes the others on to the task's hooks, where this env reads none
RESET_OPTIONS = ("env_idx", "reconfigure", "reset_to_env_states")


def check_reset_options(options) -> None:
    """``reset(options=...)``: a dict; ``reconfigure`` is a bool, ``reset_to_env_states`` a dict
    with ``env_states`` (and optionally ``obs``), as ManiSkill reads them. Other keys, which
    ManiSkill hands to the task and this env does not read, are ignored with a warning, not
    refused."""
    if options is None:
        return
    if not isinstance(options, dict):
        raise ValueError(f"reset(options={options!r}): options is a dict, e.g. {{'env_idx': [0]}}")
    ignored = sorted(map(str, set(options) - set(RESET_OPTIONS)))
    if ignored:
        warnings.warn(
            f"reset(options=...): ignored keys {ignored}; this env reads {list(RESET_OPTIONS)}",
            stacklevel=3,
        )
    if "reconfigure" in options:
        check_flag("reset(options=...): reconfigure", options["reconfigure"])
    states = options.get("reset_to_env_states", {"env_states": None})
    keys = sorted(map(str, states)) if isinstance(states, dict) else None
    if keys is None or "env_states" not in keys or not set(keys) <= {"env_states", "obs"}:
        got = type(states).__name__ if keys is None else f"keys {keys}"
        raise ValueError(
            f"reset(options=...): reset_to_env_states is a dict with 'env_states' "
            "(env.get_state_dict() or env.get_state(), one row per reset env) and optionally "
            f"'obs' (their observations); got {got}"
        )


def check_num_envs(num_envs, sim_backend: str) -> None:
    """Several envs in one process need ManiSkill's GPU simulation, hence CUDA."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, numbers.Integral) or num_envs < 1:
        raise ValueError(f"num_envs={num_envs!r} must be a positive integer")
    cpu = sim_backend in ("cpu", "physx_cpu")
    if num_envs > 1 and (cpu or not torch.cuda.is_available()):
        why = f"sim_backend={sim_backend!r}" if cpu else "this machine has no CUDA device"
        raise ValueError(
            f"num_envs={num_envs} needs ManiSkill's GPU simulation, and {why}. Fix: one env per "
            "process, vectorised with gym.make_vec('PickEmbodiedGen-v1', num_envs=N, "
            "vectorization_mode='async', wrappers=[CPUGymWrapper], "
            "vector_kwargs=dict(context='forkserver')), with ManiSkill's CPUGymWrapper "
            "(mani_skill.utils.wrappers.gymnasium)"
        )


def gpu_sim_requested(num_envs: int, sim_backend: str) -> bool:
    """Whether ManiSkill will run PhysX on the GPU: a CUDA backend named, or "auto" with
    several envs (ManiSkill's own rule)."""
    name = str(sim_backend).split(":")[0]
    return name in ("physx_cuda", "cuda", "gpu") or (name == "auto" and num_envs > 1)


def check_gpu_physics(num_envs: int, sim_backend: str) -> None:
    """ManiSkill's GPU simulation needs CUDA and PhysX's GPU library, which SAPIEN fetches from
    GitHub on first use into ``~/.sapien/physx/<version>/``; a machine that cannot reach GitHub
    would otherwise stop inside ``requests`` with a name-resolution traceback."""
    if not gpu_sim_requested(num_envs, sim_backend):
        return
    if not torch.cuda.is_available():
        raise ValueError(
            f"sim_backend={sim_backend!r} runs PhysX on the GPU and this machine has no CUDA "
            "device. Fix: sim_backend='physx_cpu' with num_envs=1 (one env per process)"
        )
    # why here: sapien.physx imports the simulator; arguments.py is imported without it
    import sapien.physx as physx

    if physx.is_gpu_enabled():
        return
    folder = Path.home() / ".sapien" / "physx" / physx.version()
    url = (
        "https://github.com/sapien-sim/physx-precompiled/releases/download/"
        f"{physx.version()}/linux-so.zip"
    )
    try:
        physx.enable_gpu()
    except Exception as err:  # requests' errors, a truncated zip, a library that fails to load
        raise RuntimeError(
            f"sim_backend={sim_backend!r} needs PhysX's GPU library "
            f"({folder / 'libPhysXGpu_64.so'}), which SAPIEN downloads from {url} on first use, "
            f"and that failed ({type(err).__name__}: {short(err)}). Fix: "
            f"download {url} on a machine with internet and unzip it into {folder} on this one"
        ) from err


def short(err: BaseException, limit: int = 120) -> str:
    """An exception's first line, cut to ``limit`` characters."""
    line = (str(err).splitlines() or [""])[0]
    return line if len(line) <= limit else line[: limit - 3] + "..."


def check_seed(seed, num_envs: int) -> None:
    """``reset(seed=...)``: None, an int in [0, 2**32), or one such int per env."""
    if seed is None:
        return
    values = seed.tolist() if isinstance(seed, np.ndarray | torch.Tensor) else seed
    many = isinstance(values, list | tuple)
    for v in values if many else [values]:
        if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not 0 <= v <= MAX_SEED:
            raise ValueError(
                f"reset(seed={seed!r}): a seed is an int in [0, {MAX_SEED}] (ManiSkill seeds "
                f"numpy RandomStates), or a list of {num_envs} such ints; got {v!r}"
            )
    if many and len(values) not in (1, num_envs):
        raise ValueError(
            f"reset(seed=...): {len(values)} seeds for {num_envs} envs; give one, or one per env"
        )


def check_env_idx(options: dict | None, num_envs: int, device) -> dict | None:
    """``reset(options=dict(env_idx=...))``: distinct env indices in [0, num_envs), as a tensor
    on the env's device (ManiSkill indexes with it)."""
    if not options or "env_idx" not in options:
        return options
    idx = options["env_idx"]
    try:
        t = torch.as_tensor(idx)
    except (TypeError, ValueError, RuntimeError):
        t = None
    ok = (
        t is not None
        and t.dim() == 1
        and len(t) > 0
        and not t.is_floating_point()
        and t.dtype != torch.bool
        and bool(((t >= 0) & (t < num_envs)).all())
        and len(torch.unique(t)) == len(t)
    )
    if not ok:
        raise ValueError(
            f"reset(options=dict(env_idx={idx!r})): env_idx is a non-empty 1-D list or tensor "
            f"of distinct integer env indices in [0, {num_envs - 1}]"
        )
    return {**options, "env_idx": t.to(device=device, dtype=torch.long)}


def check_action(action, single_shape: tuple, num_envs: int, control_mode: str):
    """The action as a tensor (lists and arrays are converted), or ``None`` / a dict as given.

    Raises:
        ValueError: for a wrong shape or NaN/inf values, naming both.
    """
    if action is None or isinstance(action, dict):
        return action  # ManiSkill's own meanings (no-op, multi-agent)
    if (
        type(action) is np.ndarray and action.dtype == np.float32
        and action.shape in (single_shape, (num_envs, *single_shape))
        and np.isfinite(action).all()
    ):  # fmt: skip
        return torch.from_numpy(action)  # a policy's usual action, checked in numpy (a third
        # of the torch checks' cost); the general path below gives the same tensor
    try:
        a = torch.as_tensor(np.asarray(action) if isinstance(action, list | tuple) else action)
    except (TypeError, ValueError, RuntimeError) as e:
        raise ValueError(f"action must be numbers of shape {single_shape}: {e}") from None
    if tuple(a.shape) not in (single_shape, (num_envs, *single_shape)):
        raise ValueError(
            f"action has shape {tuple(a.shape)}; PickEmbodiedGen-v1 with control_mode="
            f"{control_mode!r} takes {single_shape} or "
            f"({num_envs}, {single_shape[0]})"
        )
    if not a.is_floating_point():
        a = a.float()
    finite = torch.isfinite(a.reshape(-1, *single_shape)).all(dim=1)
    if not bool(finite.all()):
        bad = (~finite).nonzero().reshape(-1).tolist()
        raise ValueError(
            f"action contains NaN or inf (env {bad}); check the policy's output before "
            "stepping, the simulation state would become NaN"
        )
    return a
