"""Simulation displacement (S.D.): does the grasp hold the object? (docs/method.md section 3)

The ObMan / GraspTTA / EasyHOI protocol in PyBullet: the hand is a static concave triangle mesh,
the object a dynamic body of mass 1 kg made of the convex hulls of its V-HACD decomposition, with
its centre of mass at its vertex mean. Gravity (9.8 m/s^2) points along +y of the camera frame
(image down). After ``steps`` steps of 1/240 s, the displacement is the distance between the
object's final position and its initial centroid, in cm.

Convex decompositions are cached per mesh (content hash of the centred vertices, the faces and
the V-HACD parameters) in memory and on disk under ``$EASYHOI_CACHE/vhacd`` (default
``~/.cache/easyhoi/vhacd``); files are written under temporary names and renamed.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from easyhoi.errors import BackendError, InvalidInputError, require
from easyhoi.io.native_output import silenced
from easyhoi.metrics._common import M_TO_CM, as_mesh, to_numpy

logger = logging.getLogger(__name__)

_MEMORY_CACHE: dict[str, tuple[Path, int]] = {}


@dataclass(frozen=True)
class VHACDParams:
    """V-HACD settings of the published protocol (docs/method.md).

    PyBullet bundles V-HACD 2.2, which has no "maximum number of hulls" setting: it bounds the
    count by its clipping depth (each stage at most doubles the parts), so ``max_hulls`` is
    passed as ``depth = ceil(log2(max_hulls))`` (1024 -> 10).
    """

    resolution: int = 1000  #: voxels used by the voxelization stage
    concavity: float = 0.001  #: maximum allowed concavity
    max_hulls: int = 1024
    max_vertices_per_hull: int = 64
    min_volume_per_hull: float = 1e-4

    def pybullet_kwargs(self) -> dict:
        return {
            "resolution": int(self.resolution),
            "concavity": float(self.concavity),
            "depth": max(1, int(np.ceil(np.log2(max(2, int(self.max_hulls)))))),
            "maxNumVerticesPerCH": int(self.max_vertices_per_hull),
            "minVolumePerCH": float(self.min_volume_per_hull),
        }


@dataclass(frozen=True)
class Decomposition:
    """A cached convex decomposition.

    Attributes:
        path (Path): OBJ file, one ``o`` group per convex hull, in the object's frame translated so
            that its vertex mean is the origin (metres).
        n_hulls (int): Number of convex hulls.
        centre ((3,) float): The object's vertex mean in its original frame (metres).
        cache (str): Where it came from: "memory", "disk" or "computed".
        seconds (float): Time spent obtaining it.
    """

    path: Path
    n_hulls: int
    centre: np.ndarray
    cache: str
    seconds: float


@dataclass(frozen=True)
class SimResult:
    """Outcome of one simulation.

    Attributes:
        displacement (float): |final object position - initial centroid|, cm.
        initial_position, final_position ((3,) float): Object centre of mass before and after,
            metres.
        steps (int): Simulation steps run.
        n_hulls (int): Convex hulls in the object's decomposition.
        cache (str): "memory", "disk" or "computed" (the decomposition's origin).
        decomposition_seconds, simulation_seconds (float): Wall-clock times.
    """

    displacement: float
    initial_position: np.ndarray
    final_position: np.ndarray
    steps: int
    n_hulls: int
    cache: str
    decomposition_seconds: float
    simulation_seconds: float
    settings: dict = field(default_factory=dict)


def _pybullet():
    """The pybullet module, or MissingDependencyError saying how to get it.

    pybullet publishes no wheel for Python 3.12 and later, so it is a dependency only below
    3.12; there ``pip install 'easyhoi[sim]'`` builds it from source (a C++ compiler is needed).
    """
    return require(
        "pybullet",
        extra="sim",
        purpose="the simulation displacement metric (S.D.); from Python 3.12 on it is built from "
        "source, which needs a C++ compiler",
    )


def default_cache_dir() -> Path:
    """``$EASYHOI_CACHE/vhacd`` when set, else ``~/.cache/easyhoi/vhacd``."""
    root = os.environ.get("EASYHOI_CACHE")
    return Path(root) / "vhacd" if root else Path.home() / ".cache" / "easyhoi" / "vhacd"


def clear_memory_cache() -> None:
    """Forget the in-memory decompositions (the disk cache is kept)."""
    _MEMORY_CACHE.clear()


def _count_hulls(path: Path) -> int:
    n_groups = n_vertices = 0
    with open(path) as fh:
        for line in fh:
            n_groups += line.startswith("o ")
            n_vertices += line.startswith("v ")
    return n_groups if n_vertices else 0


def _mesh_key(vertices: np.ndarray, faces: np.ndarray, params: VHACDParams) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(faces, dtype="<i8").tobytes())
    h.update(repr(sorted(asdict(params).items())).encode())
    return h.hexdigest()[:32]


def convex_decomposition(
    obj_mesh, params: VHACDParams | None = None, cache_dir: str | os.PathLike | None = None
) -> Decomposition:
    """V-HACD convex decomposition of an object, cached in memory and on disk.

    Args:
        obj_mesh (trimesh.Trimesh or (vertices (V, 3), faces (F, 3))): Object mesh in metres.
        params (VHACDParams, optional): Decomposition settings (default: the published ones).
        cache_dir (path, optional): Disk cache folder (default: :func:`default_cache_dir`).

    Returns:
        Decomposition
    """
    p = _pybullet()

    t0 = time.perf_counter()
    params = params or VHACDParams()
    mesh = as_mesh(obj_mesh, "obj_mesh")
    centre = np.asarray(mesh.vertices).mean(0)
    # rounded to 1 nm so that translated copies share one cache entry
    centred = np.round(np.asarray(mesh.vertices) - centre, 9) + 0.0  # no negative zeros
    key = _mesh_key(centred, mesh.faces, params)
    hit = _MEMORY_CACHE.get(key)
    if hit is not None and hit[0].is_file():
        return Decomposition(hit[0], hit[1], centre, "memory", time.perf_counter() - t0)
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / f"{key}.obj"
    if final.is_file() and (n := _count_hulls(final)) > 0:
        _MEMORY_CACHE[key] = (final, n)
        return Decomposition(final, n, centre, "disk", time.perf_counter() - t0)

    tmp = []
    try:
        for suffix in (".in.obj", ".out.obj", ".log"):
            fd, name = tempfile.mkstemp(prefix=f".{key}-", suffix=suffix, dir=folder)
            os.close(fd)
            tmp.append(name)
        trimesh.Trimesh(centred, mesh.faces, process=False).export(tmp[0], file_type="obj")
        with silenced(1, keep_when_debug=False):  # V-HACD prints its progress on stdout
            p.vhacd(tmp[0], tmp[1], tmp[2], **params.pybullet_kwargs())
        n = _count_hulls(Path(tmp[1]))
        if n == 0:
            logger.warning("V-HACD produced no hull; falling back to the object's convex hull")
            hull = trimesh.Trimesh(centred, mesh.faces, process=False).convex_hull
            if len(hull.faces) == 0:
                raise BackendError("the object is degenerate: it has no convex hull")
            text = "o convex_0\n" + "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in hull.vertices)
            text += "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in hull.faces)
            Path(tmp[1]).write_text(text)
            n = 1
        os.replace(tmp[1], final)
    finally:
        for name in tmp:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(name)
    _MEMORY_CACHE[key] = (final, n)
    seconds = time.perf_counter() - t0
    logger.debug("V-HACD: %d hulls in %.2f s -> %s", n, seconds, final)
    return Decomposition(final, n, centre, "computed", seconds)


def simulation_displacement(
    hand_mesh,
    obj_mesh,
    steps: int = 35,
    gravity: float = 9.8,
    gravity_dir=(0.0, 1.0, 0.0),
    time_step: float = 1.0 / 240.0,
    solver_iterations: int = 150,
    friction: float = 3.0,
    hand_restitution: float = 0.0,
    obj_restitution: float = 0.5,
    obj_mass: float = 1.0,
    linear_damping: float | None = None,
    vhacd: VHACDParams | None = None,
    cache_dir: str | os.PathLike | None = None,
) -> SimResult:
    """Simulate the object under gravity with the hand fixed; report how far it moves.

    Args:
        hand_mesh (trimesh.Trimesh or (vertices (V, 3), faces (F, 3))): Hand mesh in metres (static
            concave triangle mesh; need not be closed).
        obj_mesh (trimesh.Trimesh or (vertices, faces)): Object mesh in metres, in the same frame as
            the hand.
        steps (int): Simulation steps: 35 in the ObMan code (default), 1000 in the EasyHOI paper's
            text.
        gravity (float): m/s^2.
        gravity_dir ((3,) float): Direction of gravity; default +y (image down in the camera frame).
        time_step (float): Seconds per step.
        solver_iterations (int): Constraint solver iterations per step.
        friction (float): Lateral friction of both bodies.
        hand_restitution, obj_restitution (float): Restitution of the hand and of the object.
        obj_mass (float): kg.
        linear_damping (float, optional): Object linear damping; None keeps PyBullet's default
            (0.04), as the published code did.
        vhacd (VHACDParams, optional): Decomposition settings.
        cache_dir (path, optional): Disk cache folder of the decompositions.

    Returns:
        SimResult: ``displacement`` in cm.
    """
    p = _pybullet()

    steps = int(steps)
    if steps < 0:
        raise InvalidInputError(f"steps must be >= 0, got {steps}")
    g_dir = to_numpy(gravity_dir, "gravity_dir")
    if g_dir.shape != (3,) or not np.isfinite(g_dir).all() or np.linalg.norm(g_dir) == 0:
        raise InvalidInputError(f"gravity_dir must be a non-zero (3,) vector, got {gravity_dir}")
    for name, val in (("time_step", time_step), ("obj_mass", obj_mass)):
        if not (np.isfinite(val) and val > 0):
            raise InvalidInputError(f"{name} must be positive, got {val}")
    hand = as_mesh(hand_mesh, "hand_mesh")
    deco = convex_decomposition(obj_mesh, vhacd, cache_dir)
    g_vec = float(gravity) * g_dir / np.linalg.norm(g_dir)

    t0 = time.perf_counter()
    cid = p.connect(p.DIRECT)
    if cid < 0:
        raise BackendError("could not start a PyBullet DIRECT client")
    try:
        kw = {"physicsClientId": cid}
        p.setGravity(*g_vec.tolist(), **kw)
        p.setPhysicsEngineParameter(
            fixedTimeStep=float(time_step), numSolverIterations=int(solver_iterations), **kw
        )
        hand_shape = p.createCollisionShape(
            p.GEOM_MESH,
            vertices=np.asarray(hand.vertices, dtype=np.float64).tolist(),
            indices=np.asarray(hand.faces, dtype=np.int64).ravel().tolist(),
            flags=p.GEOM_FORCE_CONCAVE_TRIMESH,
            **kw,
        )
        obj_shape = p.createCollisionShape(p.GEOM_MESH, fileName=str(deco.path), **kw)
        if hand_shape < 0 or obj_shape < 0:
            raise BackendError("PyBullet could not create the hand or object collision shape")
        hand_body = p.createMultiBody(baseMass=0, baseCollisionShapeIndex=hand_shape, **kw)
        start = deco.centre.tolist()
        obj_body = p.createMultiBody(
            baseMass=float(obj_mass), baseCollisionShapeIndex=obj_shape, basePosition=start, **kw
        )
        p.changeDynamics(
            hand_body, -1, lateralFriction=friction, restitution=hand_restitution, **kw
        )
        obj_dyn = {"lateralFriction": friction, "restitution": obj_restitution}
        if linear_damping is not None:
            obj_dyn["linearDamping"] = float(linear_damping)
        p.changeDynamics(obj_body, -1, **obj_dyn, **kw)
        for _ in range(steps):
            p.stepSimulation(**kw)
        final = np.asarray(p.getBasePositionAndOrientation(obj_body, **kw)[0], dtype=np.float64)
    finally:
        p.disconnect(cid)
    sim_s = time.perf_counter() - t0
    disp = float(np.linalg.norm(final - deco.centre) * M_TO_CM)
    settings = {
        "steps": steps, "gravity": g_vec.tolist(), "time_step": time_step,
        "solver_iterations": solver_iterations, "friction": friction,
        "hand_restitution": hand_restitution, "obj_restitution": obj_restitution,
        "obj_mass": obj_mass, "linear_damping": linear_damping,
        "vhacd": asdict(vhacd or VHACDParams()),
    }  # fmt: skip
    return SimResult(
        disp, deco.centre.copy(), final, steps, deco.n_hulls, deco.cache, deco.seconds, sim_s,
        settings,
    )  # fmt: skip


def gravity_cone(gravity_dir=(0.0, 1.0, 0.0), tilt_deg: float = 10.0, azimuths: int = 6):
    """Unit gravity directions: ``gravity_dir``, then ``azimuths`` directions tilted from it by
    ``tilt_deg`` at evenly spaced azimuths (the first tilted towards the world axis least
    aligned with gravity). Deterministic.

    Returns:
        (1 + azimuths, 3) float array.
    """
    g = to_numpy(gravity_dir, "gravity_dir")
    if g.shape != (3,) or not np.isfinite(g).all() or np.linalg.norm(g) == 0:
        raise InvalidInputError(f"gravity_dir must be a non-zero (3,) vector, got {gravity_dir}")
    if not (np.isfinite(tilt_deg) and 0 <= tilt_deg < 90):
        raise InvalidInputError(f"tilt_deg must be in [0, 90), got {tilt_deg}")
    if int(azimuths) < 0:
        raise InvalidInputError(f"azimuths must be >= 0, got {azimuths}")
    g = g / np.linalg.norm(g)
    a = np.eye(3)[int(np.argmin(np.abs(g)))]
    u = a - (a @ g) * g
    u /= np.linalg.norm(u)
    w = np.cross(g, u)
    t = np.radians(float(tilt_deg))
    out = [g]
    for k in range(int(azimuths)):
        phi = 2.0 * np.pi * k / int(azimuths)
        out.append(np.cos(t) * g + np.sin(t) * (np.cos(phi) * u + np.sin(phi) * w))
    return np.stack(out)


def cone_displacement(
    hand_mesh, obj_mesh, gravity_dir=(0.0, 1.0, 0.0), tilt_deg: float = 10.0,
    azimuths: int = 6, **kwargs,
) -> tuple[float, list[float]]:  # fmt: skip
    """S.D. averaged over a cone of gravity directions (:func:`gravity_cone`), in cm.

    A lower-variance companion of :func:`simulation_displacement` (same keyword arguments):
    whether a grasp holds can flip with millimetre changes of the hand, and averaging over
    slightly tilted gravity measures how robustly it holds. The convex decomposition is
    computed once (cached). Returns ``(mean displacement, per-direction displacements)``.
    """
    dirs = gravity_cone(gravity_dir, tilt_deg, azimuths)
    per = [
        simulation_displacement(hand_mesh, obj_mesh, gravity_dir=d, **kwargs).displacement
        for d in dirs
    ]
    return float(np.mean(per)), per
