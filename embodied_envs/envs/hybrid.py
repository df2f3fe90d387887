"""Hybrid rendering: simulated foreground composited over a Gaussian-splat background.

:class:`HybridRenderer` owns all hybrid state of one env instance: the splat, the foreground
ids of every env, every env's background pose, and per camera the stacked backgrounds of all
envs on the env's device. The env calls it at (re)configuration
(:meth:`HybridRenderer.configure`), after the reset that follows it
(:meth:`HybridRenderer.prerender`), for sensor observations
(:meth:`HybridRenderer.composite_sensors`) and for ``render()`` (:meth:`HybridRenderer.render`).

Per (camera, env) the background splat is rendered once, posed by that env's layout, and
re-rendered only when that env's camera or background pose changes; the envs due are rendered
together, in batched rasterizer calls (each env's camera moved into the splat's frame).
Compositing is one batched tensor operation over envs: a pixel is foreground when its
segmentation id is one of its env's foreground ids (robot links and layout actors, given
explicitly); with the depth test on, a foreground pixel farther than the splat surface shows
the background.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from mani_skill.utils.visualization.misc import tile_images

from embodied_envs.layout.pose import LayoutPose
from embodied_envs.splat import PinholeCamera, SplatFileError, pose_splat, read_ply, render
from embodied_envs.splat.backend import resolve_backend

SPLAT_SURFACE_ALPHA = 0.5  # splat pixels at least this opaque have a surface for the depth test
CAMERA_TOLERANCE = 1e-6  # camera matrices closer than this reuse the cached background
# backgrounds rendered per batched rasterizer call: at most 64 cameras, and cameras x Gaussians
# at most 2^24 (the projection holds a (cameras, Gaussians, 3) tensor: 200 MB at float32)
MAX_CAMERAS_PER_CALL = 64
MAX_CAMERA_GAUSSIANS_PER_CALL = 1 << 24
MAX_CACHED_VIEWS = 64  # (room, camera) backgrounds kept for rooms drawn again (~1 MB at 256x256)
DEPTH_MM_MAX = 32767  # ManiSkill's depth and position textures are int16 millimetres


@dataclass
class CameraBackgrounds:
    """One camera's backgrounds of every env, stacked on the env's device."""

    model: torch.Tensor  # (n, 4, 4) float64 camera-to-world (OpenGL) they were rendered for
    intrinsic: torch.Tensor  # (n, 3, 3) float64
    rgb: torch.Tensor  # (n, H, W, 3) uint8
    depth: torch.Tensor  # (n, H, W) float32, metres along the camera axis; +inf: no surface
    valid: torch.Tensor  # (n,) bool: False until rendered for the current configuration


class HybridRenderer:
    """Background cache and batched compositing for one env instance.

    Args:
        rooms: each background splat the env's layouts use, ``{gs_model.ply: layout file}``
            (Y-up, as stored; the layout file is named in errors).
        init_quat_xyzw: rotation taking the stored splat to Z-up, applied before the layout pose.
        depth_test: hide foreground pixels behind the splat surface.
        backend: splat backend, ``"auto"``, ``"torch"`` or ``"gsplat"``.
        device: where backgrounds are rendered and kept (the env's device).

    Raises:
        SplatFileError: a splat file is missing or malformed.
        ValueError: the backend cannot run here.
    """

    def __init__(
        self,
        rooms: dict[Path, str | os.PathLike],
        init_quat_xyzw: tuple[float, float, float, float],
        depth_test: bool = True,
        backend: str = "auto",
        device: torch.device | str = "cpu",
    ):
        for splat_path, layout_file in rooms.items():
            if not Path(splat_path).is_file():
                raise SplatFileError(
                    Path(splat_path),
                    f'hybrid rendering (render_mode="hybrid" or hybrid_obs=True) needs the '
                    f"background splat of {layout_file}, and this file does not exist",
                    "put a 3DGS gs_model.ply in the background's asset folder "
                    "(`embodied-envs splat from-mesh MESH --out gs_model.ply` makes one from a "
                    'mesh), or use render_mode="rgb_array" and hybrid_obs=False',
                )
        self.backend = resolve_backend(backend)
        self.device = torch.device(device)
        x, y, z, w = (float(v) for v in init_quat_xyzw)
        self._init_wxyz = torch.tensor([w, x, y, z])
        self.splats = {}  # room -> its splat, turned Z-up
        for path in rooms:
            self.add_room(Path(path), read_ply(path))
        self.depth_test = bool(depth_test)
        self.poses: list[LayoutPose] = []  # per env, the background node's layout pose
        self.rooms: list[Path] = []  # per env, its splat file
        self._lut: dict[str, torch.Tensor] = {}  # "sensor" / "human" -> (n, max id + 1) bool
        self._cameras: dict[str, CameraBackgrounds] = {}
        self._views: dict[tuple, tuple[torch.Tensor, torch.Tensor]] = {}  # (room, camera) views
        # sensor camera -> (n, H, W) bool: pixels of its last composite showing splat points
        self.splat_points: dict[str, torch.Tensor] = {}
        self._prerender_due = False  # set by configure, cleared by prerender
        self.renders = 0  # background renders so far
        self.render_seconds = 0.0  # time spent in them

    def add_room(self, room: Path, splat) -> None:
        """Make ``splat`` (a ``GaussianSplat`` in the frame rooms are stored in) the room named
        ``room``: turned Z-up once here; each env's layout pose moves the camera instead."""
        self.splats[Path(room)] = pose_splat(splat, torch.zeros(3), self._init_wxyz).to(self.device)

    # --- configuration -------------------------------------------------------------------
    def to(self, device: torch.device | str) -> HybridRenderer:
        """Keep the splat and every background on ``device`` (cached backgrounds are dropped)."""
        device = torch.device(device)
        if device != self.device:
            self.device = device
            self.splats = {k: v.to(device) for k, v in self.splats.items()}
            self._lut = {k: v.to(device) for k, v in self._lut.items()}
            self._cameras.clear()
            self._views.clear()
        return self

    def configure(
        self,
        foreground_ids: torch.Tensor,
        hidden_ids: torch.Tensor,
        background_poses: list[LayoutPose],
        rooms: list[Path],
    ) -> None:
        """Set every env's foreground ids, background pose and room; cached backgrounds go
        stale.

        Args:
            foreground_ids: ``(n, k)`` per-scene segmentation ids drawn over the background in
                every camera (robot links, layout actors).
            hidden_ids: ``(n, h)`` ids drawn only in human cameras (objects hidden from
                sensors, such as the goal marker).
            background_poses: per env, the layout pose of the background node.
            rooms: per env, its splat file (one of the renderer's ``rooms``).
        """
        n = foreground_ids.shape[0]
        human = torch.cat([foreground_ids, hidden_ids], 1).to(self.device, torch.long)
        size = int(human.max()) + 1
        rows = torch.arange(n, device=self.device)[:, None]
        for camera_kind, ids in (
            ("sensor", foreground_ids.to(self.device, torch.long)),
            ("human", human),
        ):
            lut = torch.zeros((n, size), dtype=torch.bool, device=self.device)
            lut[rows.expand_as(ids), ids] = True
            self._lut[camera_kind] = lut
        self.poses = list(background_poses)
        self.rooms = [Path(r) for r in rooms]
        for cam in self._cameras.values():
            cam.valid[:] = False
        self._prerender_due = True

    def set_rooms(self, envs: list[int], rooms: list[Path]) -> None:
        """Put env ``envs[k]`` in room ``rooms[k]`` (one of the renderer's rooms); its cached
        backgrounds go stale where its room changed, and the human cameras' are rendered
        again at the next :meth:`prerender`."""
        changed = [e for e, room in zip(envs, rooms, strict=True) if self.rooms[e] != Path(room)]
        for e, room in zip(envs, rooms, strict=True):
            self.rooms[e] = Path(room)
        if changed:
            for cam in self._cameras.values():
                cam.valid[changed] = False
            self._prerender_due = True

    # --- backgrounds ---------------------------------------------------------------------
    def render_backgrounds(
        self, cameras: list[PinholeCamera], poses: list[LayoutPose], rooms: list[Path]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The splat ``rooms[k]`` posed by ``poses[k]`` seen from ``cameras[k]`` (cameras of one
        size): uint8 RGB ``(k, H, W, 3)`` and surface depth ``(k, H, W)``. Views that are the
        same (room, camera in the room's frame) are rendered once; each room's views in
        batched rasterizer calls (``MAX_CAMERAS_PER_CALL``, ``MAX_CAMERA_GAUSSIANS_PER_CALL``)."""
        start = time.perf_counter()
        moved = [cam.in_frame(pose.matrix()) for cam, pose in zip(cameras, poses, strict=True)]
        keys = [(room, cam.key()) for room, cam in zip(rooms, moved, strict=True)]
        if all(k in self._views for k in keys):  # each view seen before (a room drawn again)
            rgb = torch.stack([self._views[k][0] for k in keys])
            return rgb, torch.stack([self._views[k][1] for k in keys])
        views: dict[tuple, int] = {}  # (room, camera) -> row of the unique views
        rows = [views.setdefault(k, len(views)) for k in keys]
        unique = [next(moved[k] for k, r in enumerate(rows) if r == v) for v in range(len(views))]
        rgb = torch.zeros((len(views), moved[0].height, moved[0].width, 3), dtype=torch.uint8,
                          device=self.device)  # fmt: skip
        depth = torch.zeros((len(views), moved[0].height, moved[0].width), device=self.device)
        for room in dict.fromkeys(rooms):
            splat = self.splats[room]
            idx = [v for (r, _), v in views.items() if r == room]
            per_call = max(
                1, min(MAX_CAMERAS_PER_CALL, MAX_CAMERA_GAUSSIANS_PER_CALL // len(splat))
            )
            for i in range(0, len(idx), per_call):
                part = idx[i : i + per_call]
                image = render(splat, [unique[v] for v in part], backend=self.backend)
                rgb[part] = image.rgb_uint8().to(self.device)
                depth[part] = image.surface_depth(SPLAT_SURFACE_ALPHA).to(self.device)
        self.renders += len(views)
        self.render_seconds += time.perf_counter() - start
        for key, row in views.items():  # kept for the next draw of the same room and camera
            if len(self._views) >= MAX_CACHED_VIEWS:
                self._views.pop(next(iter(self._views)))
            self._views[key] = (rgb[row].clone(), depth[row].clone())
        return rgb[rows], depth[rows]

    def render_one(
        self, camera: PinholeCamera, pose: LayoutPose, room: Path | None = None
    ) -> tuple[torch.Tensor, ...]:
        """The splat ``room`` (default: the only one) posed by ``pose`` seen from ``camera``:
        uint8 RGB and surface depth."""
        room = next(iter(self.splats)) if room is None else Path(room)
        rgb, depth = self.render_backgrounds([camera], [pose], [room])
        return rgb[0], depth[0]

    def backgrounds(
        self,
        camera_name: str,
        cam_to_world_gl: torch.Tensor,
        intrinsic: torch.Tensor,
        width: int,
        height: int,
    ) -> CameraBackgrounds:
        """Every env's background for one camera, rendering only the envs whose camera moved
        or whose configuration changed.

        Args:
            camera_name: cache key of the camera.
            cam_to_world_gl: (n, 4, 4) SAPIEN model matrices (OpenGL convention).
            intrinsic: (n, 3, 3) OpenCV intrinsics.
            width, height: image size.
        """
        model = cam_to_world_gl.detach().to(self.device, torch.float64)
        k = intrinsic.detach().to(self.device, torch.float64)
        n = len(self.poses)
        cached = self._cameras.get(camera_name)
        if cached is None or tuple(cached.rgb.shape[1:3]) != (height, width):
            cached = self._cameras[camera_name] = CameraBackgrounds(
                model=model.clone(),
                intrinsic=k.clone(),
                rgb=torch.zeros((n, height, width, 3), dtype=torch.uint8, device=self.device),
                depth=torch.full((n, height, width), torch.inf, device=self.device),
                valid=torch.zeros(n, dtype=torch.bool, device=self.device),
            )
        moved = ((model - cached.model).abs().amax((1, 2)) > CAMERA_TOLERANCE) | (
            (k - cached.intrinsic).abs().amax((1, 2)) > CAMERA_TOLERANCE
        )
        stale = (~cached.valid | moved).nonzero().reshape(-1).tolist()
        if stale:  # only at (re)configuration or when a camera moves
            model_np, k_np = model.cpu().numpy(), k.cpu().numpy()
            cameras = [
                PinholeCamera.from_opengl(model_np[e], k_np[e], width, height) for e in stale
            ]
            rgb, depth = self.render_backgrounds(
                cameras, [self.poses[e] for e in stale], [self.rooms[e] for e in stale]
            )
            cached.rgb[stale], cached.depth[stale] = rgb, depth
            cached.model[stale], cached.intrinsic[stale] = model[stale], k[stale]
            cached.valid[stale] = True
        return cached

    def preload(self, camera_name: str, backgrounds: CameraBackgrounds) -> None:
        """Use given backgrounds for a camera (rows marked valid are not rendered again)."""
        self._cameras[camera_name] = backgrounds

    def cached(self, camera_name: str) -> CameraBackgrounds | None:
        """The stacked backgrounds of a camera, if any were rendered."""
        return self._cameras.get(camera_name)

    # --- compositing ---------------------------------------------------------------------
    def composite(
        self,
        camera_name: str,
        images: dict[str, torch.Tensor],
        cam_to_world_gl: torch.Tensor,
        intrinsic: torch.Tensor,
        human: bool,
        textures: tuple[str, ...] = ("rgb", "depth", "segmentation", "position"),
    ) -> dict[str, torch.Tensor]:
        """Composite a batch of camera images over their backgrounds, all envs at once.

        One mask decides every texture: a pixel shows the simulator when its segmentation id is
        one of its env's foreground ids (and, with the depth test, it is not behind the splat
        surface); elsewhere it shows the splat: its colour, its surface depth (0 where the
        splat has no surface, as the simulator's empty pixels), the surface point in the
        camera frame, and segmentation id 0.

        Args:
            camera_name: cache key of the camera.
            images: ManiSkill's camera textures of the batch, ``(n, H, W, c)``: ``rgb`` uint8,
                ``segmentation`` per-scene ids and ``depth`` int16 mm (both required), and
                optionally ``position`` (int16 mm, OpenGL camera frame).
            cam_to_world_gl: (n, 4, 4) SAPIEN model matrices (OpenGL convention).
            intrinsic: (n, 3, 3) OpenCV intrinsics.
            human: a human render camera (hidden objects such as the goal are foreground).
            textures: which to composite (those not in ``images`` are skipped); ``render()``
                needs ``rgb`` only.

        Returns:
            The composited textures, on the images' device and in their dtypes, and, with
            ``depth``, ``splat_points`` ``(n, H, W)`` bool: pixels that show a splat surface
            point.
        """
        rgb, segmentation = images["rgb"], images["segmentation"]
        n, h, w = rgb.shape[:3]
        bg = self.backgrounds(camera_name, cam_to_world_gl, intrinsic, w, h)
        mask = self.foreground_mask(segmentation, human)
        if self.depth_test:
            fg_depth = images["depth"][..., 0].to(self.device, torch.float32) / 1000.0
            mask &= fg_depth <= bg.depth

        def pick(fg: torch.Tensor, splat: torch.Tensor) -> torch.Tensor:
            fg_here = fg.to(self.device)
            out = torch.where(mask[..., None], fg_here, splat.to(fg_here.dtype))
            return out.to(fg.device)

        wanted = [t for t in textures if t in images]
        out = {"rgb": pick(rgb[..., :3], bg.rgb)} if "rgb" in wanted else {}
        if "segmentation" in wanted:
            out["segmentation"] = pick(segmentation, torch.zeros(1, device=self.device))
        if "depth" in wanted or "position" in wanted:
            # the splat's surface depth in ManiSkill's int16 millimetres; none beyond its range
            bg_mm = (bg.depth * 1000.0).round()
            splat_points = ~mask & (bg_mm <= DEPTH_MM_MAX)
            bg_mm = torch.where(splat_points, bg_mm, torch.zeros_like(bg_mm))
            out["splat_points"] = splat_points.to(rgb.device)
            if "depth" in wanted:
                out["depth"] = pick(images["depth"], bg_mm[..., None])
            if "position" in wanted:
                out["position"] = pick(images["position"], self._camera_points(bg_mm, intrinsic))
        return out

    def _camera_points(self, depth_mm: torch.Tensor, intrinsic: torch.Tensor) -> torch.Tensor:
        """``(n, H, W, 3)`` points in the OpenGL camera frame (mm) of pixels at ``depth_mm``
        ``(n, H, W)`` along the axis; pixel (u, v) is centred at (u + 0.5, v + 0.5)."""
        n, h, w = depth_mm.shape
        k = intrinsic.to(self.device, torch.float32)
        u = torch.arange(w, device=self.device, dtype=torch.float32) + 0.5
        v = torch.arange(h, device=self.device, dtype=torch.float32) + 0.5
        x = (u[None, None, :] - k[:, 0, 2, None, None]) / k[:, 0, 0, None, None] * depth_mm
        y = (v[None, :, None] - k[:, 1, 2, None, None]) / k[:, 1, 1, None, None] * depth_mm
        points = torch.stack([x, -y, -depth_mm], -1)  # OpenCV (x, y, z) -> OpenGL (x, -y, -z)
        return points.round().clamp(-DEPTH_MM_MAX, DEPTH_MM_MAX)

    def foreground_mask(self, segmentation: torch.Tensor, human: bool) -> torch.Tensor:
        """``(n, H, W)`` bool: pixels whose id is one of their env's foreground ids."""
        lut = self._lut["human" if human else "sensor"]
        seg = segmentation[..., 0].to(self.device, torch.long)
        n, size = lut.shape
        known = seg < size
        flat = seg.clamp(max=size - 1).reshape(n, -1)
        return lut.gather(1, flat).reshape(seg.shape) & known

    # --- the env's cameras ---------------------------------------------------------------
    def composite_camera(self, name: str, camera, data: dict, human: bool) -> dict:
        """Composite the textures a ManiSkill camera's ``data`` holds (its obs dict;
        segmentation and depth, which the mask needs, are fetched when missing):
        :meth:`composite`'s result."""
        textures = tuple(data)
        if "segmentation" not in data or "depth" not in data:
            data = data | camera.get_obs(rgb=False, depth=True, position=False, segmentation=True)
        return self.composite(
            name,
            data,
            camera.camera.get_model_matrix(),
            camera.camera.get_intrinsic_matrix(),
            human,
            textures,
        )

    def composite_sensors(self, scene, obs: dict) -> dict:
        """Sensor observations composited in place (and returned): of every camera with
        ``rgb``, each texture it holds (``rgb``, ``depth``, ``segmentation``, ``position``).
        Which pixels show splat surface points is kept per camera in ``splat_points``."""
        for name, data in obs.items():
            if "rgb" in data:
                out = self.composite_camera(name, scene.sensors[name], data, human=False)
                if "splat_points" in out:
                    self.splat_points[name] = out.pop("splat_points")
                data.update(out)
        return obs

    def place_splat_points(self, pointcloud: dict, sensor_param: dict) -> None:
        """Fix a ManiSkill point cloud made from composited sensors, in place.

        ManiSkill's ``sensor_data_to_pointcloud`` uses ``segmentation != 0`` as each point's
        homogeneous coordinate, so a splat point (segmentation 0) would only be rotated into
        the world: this adds each camera's translation to them and marks them valid (w = 1),
        as the simulator's own points.
        """
        xyzw, start = pointcloud["xyzw"], 0
        for name, points in self.splat_points.items():
            n, h, w = points.shape
            rows = xyzw[:, start : start + h * w]
            flat = points.reshape(n, -1).to(xyzw.device)
            t = sensor_param[name]["cam2world_gl"][:, :3, 3].to(xyzw.device, xyzw.dtype)
            rows[..., :3] += flat[..., None] * t[:, None]
            rows[..., 3] = torch.where(flat, torch.ones_like(rows[..., 3]), rows[..., 3])
            start += h * w

    def prerender(self, scene) -> None:
        """After a :meth:`configure`, render the human cameras' backgrounds of every env now
        (the env calls it once the episode has posed the cameras), not at the first frame."""
        if not self._prerender_due:
            return
        self._prerender_due = False
        for name, camera in scene.human_render_cameras.items():
            self.backgrounds(
                name,
                camera.camera.get_model_matrix(),
                camera.camera.get_intrinsic_matrix(),
                camera.config.width,
                camera.config.height,
            )

    def render(self, scene, hidden_objects: list, camera_name: str | None = None) -> torch.Tensor:
        """The human render cameras' images (or ``camera_name``'s only) composited over the
        splat, ``(n, H, W, 3)`` (several cameras side by side, as ManiSkill's
        ``render_rgb_array``)."""
        for obj in hidden_objects:
            obj.show_visual()
        scene.update_render(update_sensors=False, update_human_render_cameras=True)
        images = []
        for name, camera in scene.human_render_cameras.items():
            if camera_name is not None and name != camera_name:
                continue
            camera.capture()
            data = camera.get_obs(rgb=True, depth=True, position=False, segmentation=True)
            out = self.composite(
                name, data, camera.camera.get_model_matrix(),
                camera.camera.get_intrinsic_matrix(), True, ("rgb",),
            )  # fmt: skip
            images.append(out["rgb"])
        for obj in hidden_objects:
            obj.hide_visual()
        return images[0] if len(images) == 1 else tile_images(images)


def stacked_ids(actors: list) -> torch.Tensor:
    """``(n, len(actors))`` per-scene segmentation ids of actors or links merged over envs."""
    return torch.stack([a.per_scene_id.reshape(-1) for a in actors], 1)
