"""Policies for ``embodied-envs eval``, and the checks on what they return.

Policies (:func:`load_policy`): ``expert`` (the scripted motion-planned solver, on
``pd_joint_pos``), ``random`` (uniform over the action space, seeded by the episode), ``zero``,
a TorchScript file ``path/to/policy.pt`` (a module from observations to actions, as
``tools/recipes/train_policy.py`` saves; its exported ``reset()``, if any, is called at each
episode start: a policy with state per env, e.g. temporal ensembling, clears it), or
``module:factory`` / ``path/to/file.py:factory``:
``factory(env)`` (or ``factory()``) returns a callable from observations to actions or a
``torch.nn.Module`` (its ``reset(seed)``, if any, is called at each episode start). A policy
receives the env's observation as ManiSkill returns it (torch tensors with a leading batch of 1,
as from ``ManiSkillVectorEnv``) and returns an action of shape ``(A,)`` or ``(1, A)``.

A policy's action that is not a finite array of that shape, or a policy that raises, stops the
evaluation with one :class:`EvalError` line naming the policy, the step, the episode's seed and
the expected shape; nothing is clipped or replaced. A policy's code that ends its process
(``sys.exit``, ``os._exit``: on Ray that would be a worker lost and its episode run again) is
the same line, on every backend (:func:`policy_code`).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import os
import sys
import threading
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import numpy as np

BUILTIN_POLICIES = ("expert", "random", "zero")


class EvalError(RuntimeError):
    """An evaluation that cannot run (names the policy, the episode and the fix)."""


class PolicyExit(Exception):
    """A policy's code asked its process to end (``sys.exit``, ``os._exit``): what it did, in
    words (:func:`policy_code`)."""


_real_exit = os._exit  # os._exit, for the threads that run no policy code
_in_policy: set[int] = set()  # the threads running a policy's code now


def _exit(code: int) -> None:
    """``os._exit`` once a policy has run here: from the thread running the policy's code,
    :class:`PolicyExit`; from any other (a worker's parent watch, Ray's), the process ends."""
    if threading.get_ident() in _in_policy:
        raise PolicyExit(f"called os._exit({code})")
    _real_exit(code)


@contextmanager
def policy_code():
    """Runs a policy's code (its import, factory, ``reset``, each action): an end of the
    process it asks for is :class:`PolicyExit` here, so that the process lives to say so in
    one line, as the local run does (on Ray, a worker process that ends is lost and its task
    run again). ``os._exit`` is replaced, for good, by one that raises only in the thread
    inside this block; a ``SystemExit`` of the policy's becomes :class:`PolicyExit`, Ray's own
    (its ``ray_terminate_msg``: the worker told to stop) goes on. A process that dies otherwise
    (a crash in native code, a kill) is not the policy's word: a lost worker."""
    global _real_exit
    if os._exit is not _exit:
        _real_exit, os._exit = os._exit, _exit
    thread = threading.get_ident()
    inside = thread in _in_policy
    _in_policy.add(thread)
    try:
        yield
    except SystemExit as e:
        if hasattr(e, "ray_terminate_msg"):
            raise
        text = " ".join(str(e).split())
        raise PolicyExit(f"raised SystemExit: {text}" if text else "raised SystemExit") from e
    finally:
        if not inside:
            _in_policy.discard(thread)


def _import_target(spec: str):
    """The object named by ``module:attr`` or ``path/to/file.py:attr``."""
    module_name, sep, attr = spec.rpartition(":")
    if not sep or not module_name or not attr:
        raise EvalError(
            f"--policy {spec!r} is neither a built-in ({', '.join(BUILTIN_POLICIES)}) nor "
            "module:factory. Fix: name a factory, e.g. --policy my_policy:make_policy"
        )
    try:
        if module_name.endswith(".py"):
            path = Path(module_name).resolve()
            if not path.is_file():
                raise FileNotFoundError(f"no such file {path}")
            loaded = importlib.util.spec_from_file_location(path.stem, path)
            module = importlib.util.module_from_spec(loaded)
            with policy_code():
                loaded.loader.exec_module(module)
        else:
            if os.getcwd() not in sys.path:  # as `python -m` would: the user's own modules
                sys.path.insert(0, os.getcwd())
            with policy_code():
                module = importlib.import_module(module_name)
    except PolicyExit as e:  # the module's own code ends the process as it is imported
        raise EvalError(f"--policy {spec}: importing {module_name!r} {e}") from None
    except Exception as e:  # whatever the user's module raises on import
        raise EvalError(
            f"--policy {spec}: cannot import {module_name!r} ({type(e).__name__}: {e}). Fix: "
            "run from the folder that holds it, or give the file's path (file.py:factory)"
        ) from None
    if not hasattr(module, attr):
        raise EvalError(f"--policy {spec}: {module_name!r} has no attribute {attr!r}")
    return getattr(module, attr)


class Policy:
    """A policy for :class:`EpisodeRunner`: ``reset(seed)`` at each episode start, then
    ``act(obs)`` each step."""

    def __init__(self, act: Callable, reset: Callable[[int], None] | None = None):
        self.act, self._reset = act, reset

    def reset(self, seed: int) -> None:
        if self._reset is not None:
            self._reset(seed)


def load_policy(spec: str, env) -> Policy | None:
    """The :class:`Policy` named by ``spec``; ``None`` for ``expert`` (it drives the env
    itself). A user policy with a ``reset(seed)`` method has it called at each episode start.

    Raises:
        EvalError: the policy cannot be imported or made.
    """
    if spec == "expert":
        return None
    if spec.endswith((".pt", ".ts")) and ":" not in spec:
        return _torchscript_policy(spec)
    space = env.action_space
    shape = tuple(space.shape)
    if spec == "zero":
        return Policy(lambda obs: np.zeros(shape, np.float32))
    if spec == "random":  # uniform over the action space, drawn from the episode's seed
        low, high = np.asarray(space.low), np.asarray(space.high)
        state = {"rng": np.random.default_rng(0)}

        def reseed(seed: int) -> None:
            state["rng"] = np.random.default_rng(seed)

        return Policy(lambda obs: state["rng"].uniform(low, high).astype(np.float32), reseed)
    factory = _import_target(spec)
    if not callable(factory):
        raise EvalError(f"--policy {spec}: {type(factory).__name__} is not callable")
    try:
        takes_env = bool(inspect.signature(factory).parameters)
    except (TypeError, ValueError):
        takes_env = False
    try:
        with policy_code():
            made = factory(env) if takes_env else factory()
    except Exception as e:  # the user's code (an exit too: policy_code)
        raise policy_raised(spec, "the factory", e) from None
    import torch  # in the process that runs episodes; `embodied-envs --help` stays without it

    reset = getattr(made, "reset", None)
    reset = reset if callable(reset) else None
    if isinstance(made, torch.nn.Module):
        module = made.eval()

        def run_module(obs):
            with torch.no_grad():
                return module(obs)

        return Policy(run_module, reset)
    if not callable(made):
        raise EvalError(
            f"--policy {spec}: the factory returned a {type(made).__name__}, not a callable "
            "from observations to actions or a torch.nn.Module"
        )
    return Policy(made, reset)


def _torchscript_policy(spec: str) -> Policy:
    """A TorchScript module saved at ``spec`` (``torch.jit.save``), run without gradients."""
    import torch  # in the process that runs episodes; `embodied-envs --help` stays without it

    path = Path(spec)
    if not path.is_file():
        raise EvalError(f"--policy {spec}: no such file. Fix: give the path of a saved policy")
    try:
        module = torch.jit.load(str(path), map_location="cpu").eval()
    except Exception as e:  # whatever torch says about a file that is not TorchScript
        text = " ".join(str(e).split())[:200]
        raise EvalError(
            f"--policy {spec}: not a TorchScript module ({type(e).__name__}: {text}). Fix: save "
            "it with torch.jit.save(torch.jit.script(model), path), or use module:factory"
        ) from None

    reset = getattr(module, "reset", None)  # a scripted module's exported reset(), if any
    camera = getattr(module, "camera", None)  # a visual policy (train_policy.py on frames)
    inputs = _visual_inputs(spec, module) if camera is not None else None

    def run(obs):
        if inputs is not None:
            with torch.no_grad():
                return module(*inputs(obs))
        if not isinstance(obs, torch.Tensor):
            raise TypeError(
                f"a TorchScript policy takes a tensor observation, got {type(obs).__name__}: "
                "evaluate it with --obs-mode state"
            )
        with torch.no_grad():
            return module(obs.float())

    return Policy(run, None if reset is None else lambda seed: reset())


def _visual_inputs(spec: str, module) -> Callable:
    """For a visual TorchScript policy (its ``camera``, ``obs_keys`` and ``image_hw``), the
    function from the env's observation to its ``(image, state)``; an observation without that
    camera's frames, or frames of another size, is one line naming the flag that fixes it."""
    import torch  # in the process that runs episodes

    camera, keys = str(module.camera), [str(k) for k in module.obs_keys]
    hw = tuple(int(v) for v in module.image_hw)

    def inputs(obs):
        if not isinstance(obs, dict) or camera not in obs.get("sensor_data", {}):
            raise TypeError(
                f"{spec} is a visual policy (trained on {camera} frames of {hw[0]}x{hw[1]}); "
                "this observation has none: evaluate it with --obs-mode rgb (and --hybrid-obs "
                "if it was trained on hybrid frames)"
            )
        image = obs["sensor_data"][camera]["rgb"]
        if tuple(image.shape[1:3]) != hw:
            raise TypeError(
                f"{spec} was trained on {hw[0]}x{hw[1]} frames; the env gives "
                f"{image.shape[1]}x{image.shape[2]}: evaluate it with --camera-size {hw[0]}"
            )
        state = [obs[group][name].float().reshape(image.shape[0], -1)
                 for group, name in (key.split("/", 1) for key in keys)]  # fmt: skip
        return image, torch.cat(state, 1)

    return inputs


def at_step(step: int, seed: int, layout: str) -> str:
    """Where in an evaluation an error happened, in words."""
    return f"at step {step} of episode seed {seed} ({Path(layout).name})"


def checked_action(action, shape: tuple[int, ...], spec: str, step: int, seed: int, layout: str):
    """The policy's action as a float32 array of ``shape``, or a one-line EvalError naming the
    policy, the step and the expected shape (a NaN is refused, never replaced)."""
    where = at_step(step, seed, layout)
    try:
        if hasattr(action, "detach"):
            action = action.detach().cpu().numpy()
        arr = np.asarray(action, dtype=np.float32)
    except (TypeError, ValueError) as e:
        raise EvalError(
            f"--policy {spec} returned {type(action).__name__} {where}, not an array of shape "
            f"{shape}: {e}"
        ) from None
    if arr.shape != shape and arr.shape != (1, *shape):
        raise EvalError(
            f"--policy {spec} returned an action of shape {arr.shape} {where}; the env's action "
            f"space is {shape}. Fix: return (A,) or (1, A), or pass the --control-mode it was "
            "trained with"
        )
    if not np.isfinite(arr).all():
        raise EvalError(
            f"--policy {spec} returned a non-finite action (NaN or inf) {where}; expected finite "
            f"values of shape {shape}"
        )
    return arr.reshape(shape)


def policy_raised(spec: str, call: str, error: Exception, where: str = "") -> EvalError:
    """The one-line error for a policy whose ``call`` raised ``error`` (its own message kept),
    or ended its process (:class:`PolicyExit`)."""
    text = " ".join(str(error).split())
    did = text if isinstance(error, PolicyExit) else f"raised {type(error).__name__}: {text}"
    return EvalError(" ".join(filter(None, (f"--policy {spec}: {call} {did}", where))))


def policy_driver(policy: Policy, spec: str):
    """The episode driver (``pipelines.episodes.Driver``) of ``policy`` (named ``spec``): its
    ``reset(seed)``, then an action per step until ManiSkill's ``terminated`` or ``truncated``
    or the env's episode limit; each action checked (:func:`checked_action`), and the user's
    code raising is one line naming the call, the step and the seed."""

    def drive(tally, obs, seed: int) -> list:
        import torch  # in the process that runs episodes; `embodied-envs --help` stays without it

        env = tally.env
        drawn = str(env.unwrapped.layouts[0].source)
        shape = tuple(env.action_space.shape)
        try:
            with policy_code():
                policy.reset(seed)
        except Exception as e:  # the user's code (an exit too: policy_code): one line
            raise policy_raised(spec, "reset(seed)", e, at_step(0, seed, drawn)) from e
        limit = env.spec.max_episode_steps if env.spec is not None else None
        while limit is None or tally.steps < limit:
            try:
                with policy_code():
                    raw = policy.act(obs)
            except Exception as e:  # the user's code (an exit too): one line, its step
                raise policy_raised(spec, "the policy", e, at_step(tally.steps, seed, drawn)) from e
            action = checked_action(raw, shape, spec, tally.steps, seed, drawn)
            obs, _, terminated, truncated, _ = tally.step(action)
            if bool(torch.as_tensor(terminated | truncated).reshape(-1)[0]):
                break
        return []

    return drive
