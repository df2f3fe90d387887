"""A ManiSkill ``BaseEnv`` whose public calls check their arguments before simulating.

Task files subclass :class:`CheckedEnv` and keep to the task; this class holds what every env of
the package does the same way: render-mode and ``num_envs`` checks, ``reset`` seed and
``env_idx`` checks (gymnasium's generator follows the seed too), every ``reset`` option ManiSkill
reads (``reset_to_env_states`` too, so its ``CachedResetWrapper`` works), ``agent.init_qpos``
as EmbodiedGen's env sets it, action checks on ``step``, a closed-env guard, a spec whose id
names the package and whose ``layout_file`` is absolute (RecordEpisode stores both), fresh
sensor parameters per call, and ``render_mode="human"`` without a display.
"""

from __future__ import annotations

import dataclasses
import inspect
import numbers
import os
import types
import typing
from pathlib import Path

import numpy as np
import torch
from gymnasium.utils import seeding
from mani_skill.envs.sapien_env import BaseEnv

from embodied_envs.config import load_config, merge_config
from embodied_envs.envs.arguments import (
    check_action,
    check_env_idx,
    check_flag,
    check_gpu_physics,
    check_num_envs,
    check_reset_options,
    check_seed,
)


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class CheckedEnv(BaseEnv):
    SUPPORTED_RENDER_MODES = ("human", "rgb_array", "sensors", "all")

    def __init__(self, *args, num_envs: int = 1, render_mode: str | None = None, **kwargs):
        if render_mode is not None and render_mode not in self.SUPPORTED_RENDER_MODES:
            raise ValueError(
                f"render_mode={render_mode!r} is not supported; use one of "
                f"{list(self.SUPPORTED_RENDER_MODES)} or None"
            )
        check_num_envs(num_envs, kwargs.get("sim_backend", "auto"))
        check_gpu_physics(num_envs, kwargs.get("sim_backend", "auto"))
        super().__init__(*args, num_envs=num_envs, render_mode=render_mode, **kwargs)

    @property
    def spec(self):
        return self.__dict__.get("_spec")

    @spec.setter
    def spec(self, spec) -> None:
        # gymnasium sets the spec that RecordEpisode stores as env_id and env_kwargs: the id
        # carries its package ("embodied_envs:PickEmbodiedGen-v1"; gymnasium imports the module
        # before the ":" on make, so ManiSkill's replay_trajectory, which imports only
        # mani_skill, finds the env), the layout files are absolute (a folder or glob as the
        # files it named) and the config files' values spelled out, so a recorded dataset
        # re-creates the env from any working directory
        if spec is not None:
            kwargs = self.env_kwargs(**spec.kwargs)
            for key, value in kwargs.items():  # an array given directly: JSON's list
                if isinstance(value, np.ndarray):
                    kwargs[key] = value.tolist()
            if kwargs.get("layout_file") is not None:  # a set: its files, spelled out
                files = self.__dict__.get("layout_file", kwargs["layout_file"])
                kwargs["layout_file"] = (
                    [str(Path(f).resolve()) for f in files]
                    if isinstance(files, list | tuple)
                    else str(Path(files).resolve())
                )
            spec = dataclasses.replace(spec, id=self.module_id(spec.id), kwargs=kwargs)
        self.__dict__["_spec"] = spec

    @classmethod
    def module_id(cls, env_id: str) -> str:
        """``env_id`` prefixed by the package that registers it (``package:id``), unless it
        names a module already."""
        return env_id if ":" in env_id else f"{cls.__module__.partition('.')[0]}:{env_id}"

    @classmethod
    def keywords(cls) -> tuple[str, ...]:
        """Every keyword the env's constructor accepts, its own and ManiSkill's."""
        names = {
            p.name
            for klass in cls.__mro__
            if "__init__" in vars(klass) and issubclass(klass, BaseEnv)
            for p in inspect.signature(klass.__init__).parameters.values()
            if p.kind is p.KEYWORD_ONLY or p.kind is p.POSITIONAL_OR_KEYWORD
        }
        return tuple(sorted(names - {"self"}))

    @classmethod
    def keyword_types(cls) -> dict:
        """Each keyword's annotation (the subclass's where several classes declare one)."""
        hints: dict = {}
        for klass in reversed(cls.__mro__):
            if "__init__" in vars(klass) and issubclass(klass, BaseEnv):
                hints.update(typing.get_type_hints(klass.__init__))
        hints.pop("return", None)
        return hints

    @classmethod
    def check_keyword(cls, name: str, value) -> None:
        """Refuse a keyword value whose type does not fit the constructor's annotation (a
        boolean is a boolean, not a string that reads "false"). Subclasses add ranges.

        Raises:
            ValueError: naming the keyword, the value and the expected type.
        """
        hint = cls.keyword_types().get(name)
        if hint is bool:
            check_flag(name, value)
        elif hint is not None and not value_fits(value, hint):
            raise ValueError(f"{name}={value!r} must be {describe_type(hint)}")

    @classmethod
    def env_kwargs(cls, config=None, **kwargs) -> dict:
        """The env's keywords: the ``config`` files merged in order, then ``kwargs`` over them.

        Raises:
            embodied_envs.config.ConfigError: a file that cannot be read, an unknown key, or a
                value of the wrong type or range (naming the file and the key).
        """
        return merge_config(load_config(config, cls.keywords(), cls.check_keyword), kwargs)

    def _reconfigure(self, options: dict | None = None):
        options = {} if options is None else options
        if self.render_mode == "human" and not has_display():
            # headless: no viewer window; "human" then returns the render camera's frames
            self.render_mode = "rgb_array"
            try:
                super()._reconfigure(options)
            finally:
                self.render_mode = "human"
        else:
            super()._reconfigure(options)

    def render_human(self):
        if has_display():
            super().render_human()
        return self.render_rgb_array()

    def reset(self, seed: int | list[int] | None = None, options: dict | None = None):
        self._check_open("reset")
        check_seed(seed, self.num_envs)
        check_reset_options(options)
        options = check_env_idx(options, self.num_envs, self.device)
        if seed is not None:
            # gymnasium's own generator follows the reset seed too, as gymnasium's checker and
            # wrappers expect (ManiSkill only seeds its episode RNGs); nothing here draws from it
            first = np.asarray(seed).reshape(-1)[0]
            self._np_random, self._np_random_seed = seeding.np_random(int(first))
        result = super().reset(seed=seed, options=options)
        self._note_init_qpos(None if options is None else options.get("env_idx"))
        return result

    def _note_init_qpos(self, env_idx: torch.Tensor | None) -> None:
        """``agent.init_qpos``: each env's joint positions at its episode's start, ``(num_envs,
        dof)``, as EmbodiedGen's env sets it (its scripts step ``init_qpos[:, :8]`` as a hold
        action and reset the agent to it); the reset envs' rows only on a partial reset."""
        robot = getattr(self.agent, "robot", None)
        if robot is None:  # no agent, or several
            return
        qpos = robot.get_qpos().clone()
        old = getattr(self.agent, "init_qpos", None)
        if env_idx is not None and isinstance(old, torch.Tensor) and old.shape == qpos.shape:
            old[env_idx] = qpos[env_idx]
        else:
            self.agent.init_qpos = qpos

    def step(self, action):
        self._check_open("step")
        shape = self.single_action_space.shape
        if shape is None and not (action is None or isinstance(action, dict)):
            keys = list(getattr(self.single_action_space, "spaces", {}))
            raise ValueError(
                f"several robots take a dict of actions, one per agent: keys {keys} (ManiSkill's "
                f"multi-agent envs); got {type(action).__name__}"
            )
        if shape is not None:
            action = check_action(action, tuple(shape), self.num_envs, self.control_mode)
        if isinstance(action, torch.Tensor):
            action = action.to(self.device)
        return super().step(action)

    def close(self):
        self._closed = True
        super().close()

    def _check_open(self, call: str) -> None:
        if self.__dict__.get("_closed"):
            name = getattr(self.spec, "id", type(self).__name__).rpartition(":")[2]
            raise RuntimeError(f"{call}() on a closed {name} env; make a new env")

    def get_sensor_params(self) -> dict[str, dict[str, torch.Tensor]]:
        # new tensors on every call: SAPIEN returns its cached intrinsic matrix, and an
        # observation must not change when a later one is taken
        return {
            name: {k: v.clone() for k, v in params.items()}
            for name, params in super().get_sensor_params().items()
        }


def value_fits(value, hint) -> bool:
    """Whether a config value (YAML/JSON: None, bool, numbers, str, lists, dicts) fits a type
    annotation; annotations it cannot judge (classes YAML cannot make) fit nothing but their
    instances, and ``Any`` fits everything."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is typing.Any:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(value_fits(value, a) for a in args)
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, numbers.Real) and not isinstance(value, bool)
    if origin in (tuple, list) or hint in (tuple, list):
        if isinstance(value, np.ndarray) and value.ndim == 1:  # passed directly to gym.make
            value = value.tolist()
        if not isinstance(value, list | tuple):
            return False
        if origin is tuple and args and args[-1] is not Ellipsis:
            return len(value) == len(args) and all(map(value_fits, value, args))
        return all(value_fits(v, args[0]) for v in value) if args else True
    if origin in (dict, typing.Mapping) or hint is dict:
        return isinstance(value, dict)
    if hint is os.PathLike:
        return isinstance(value, os.PathLike)
    return isinstance(hint, type) and isinstance(value, hint)


def describe_type(hint) -> str:
    """A type annotation in words: ``bool``, ``float``, ``str or None``, ..."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return " or ".join(describe_type(a) for a in typing.get_args(hint))
    if hint is type(None):
        return "None"
    if isinstance(hint, type) and not typing.get_args(hint):
        return {"dict": "a mapping", "str": "a string"}.get(hint.__name__, hint.__name__)
    return str(hint).replace("typing.", "")
