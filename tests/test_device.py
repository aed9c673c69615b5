"""The run's device: names, resolution, the --device flag, and where the optimizer's tensors go.

The CPU and a CUDA GPU give the same result within the tolerances docs/gpu.md states; the
"cuda" case skips where torch sees no GPU, and the same comparison runs on the CPU between the
numba and torch kernels (the kernels a GPU run uses), which differ by float rounding only.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from easyhoi.batch import ReconstructWorker
from easyhoi.cli import main
from easyhoi.config import EasyHOIConfig, get_preset, with_overrides
from easyhoi.device import check_device_name, resolve_device
from easyhoi.distributed import gpu_share
from easyhoi.errors import InvalidInputError
from easyhoi.optim.run import optimize
from easyhoi.render import soft
from easyhoi.settings import resolve_run

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA GPU")
SIZE = 64

# Same input and seed on two devices (docs/gpu.md): hand vertices and camera translation in
# object units relative to the object's extent / the translation's length, the focal length
# relative, metric values in their own units.
VERTEX_TOL = 1e-3  # x object extent, largest vertex difference
CAMERA_TOL = 1e-3  # relative focal, absolute rotation entries, relative translation
SCALE_TOL = 1e-3  # relative metric scale
METRIC_TOL = {
    "hand_mask_iou": 0.01,
    "object_mask_iou": 0.01,
    "penetration_depth_cm": 0.05,
    "contact_distance_cm": 0.05,
    "intersection_volume_cm3": 1.0,
}


@pytest.mark.parametrize("name", ["auto", "cpu", "cuda", "cuda:0", "cuda:12"])
def test_device_names_are_accepted(name):
    assert check_device_name(name) == name


@pytest.mark.parametrize("name", ["gpu", "CUDA", "cuda:", "cuda:-1", "cuda:01", "", None, 0])
def test_bad_device_names_are_refused(name):
    with pytest.raises(InvalidInputError, match="device must be one of"):
        check_device_name(name)
    with pytest.raises(InvalidInputError):
        EasyHOIConfig(device=name)


def test_auto_is_cuda_exactly_when_torch_sees_a_gpu(monkeypatch):
    assert get_preset().device == "auto"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == "cpu"
    assert resolve_device("cpu") == "cpu"
    with pytest.raises(InvalidInputError, match="torch sees no CUDA GPU"):
        resolve_device("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert resolve_device("auto") == "cuda"
    assert resolve_device("cuda:1") == "cuda:1"
    with pytest.raises(InvalidInputError, match="sees 2 GPU"):
        resolve_device("cuda:2")


def test_resolve_run_resolves_the_config_device_once(monkeypatch, hand):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    cfg = with_overrides(get_preset("fast"), {"device": "cpu"})
    assert cfg.device == "cpu"
    assert resolve_run(get_preset("fast"), hand_model=hand).device == "cpu"  # auto, no GPU
    assert resolve_run(cfg, hand_model=hand, device="auto").device == "cpu"
    with pytest.raises(InvalidInputError, match="torch sees no CUDA GPU"):
        resolve_run(replace(cfg, device="cuda"), hand_model=hand)
    worker = ReconstructWorker(replace(cfg, device="auto"))
    assert worker.device == "cpu"


def test_cli_device_cuda_without_a_gpu_exits_2(tmp_path, capsys, monkeypatch):
    from PIL import Image

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    photo = tmp_path / "p.png"
    Image.new("RGB", (32, 24), (120, 90, 60)).save(photo)
    rc = main(["reconstruct", str(photo), "--out", str(tmp_path / "o"), "--device", "cuda"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "torch sees no CUDA GPU" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
    rc = main(["reconstruct", str(photo), "--out", str(tmp_path / "o"), "--device", "tpu"])
    assert rc == 2 and "device must be one of" in capsys.readouterr().err


def test_backends_that_take_a_device_get_the_runs(monkeypatch):
    from easyhoi.perception import base
    from easyhoi.perception.chain import _backend

    class Fake:
        def __init__(self, seed: int = 0, device: str = "cpu"):
            self.seed, self.device = seed, device

    class NoDevice:
        def __init__(self, seed: int = 0):
            self.seed = seed

    base.available("inpainter")  # registers the built-in backends first
    monkeypatch.setitem(base._REGISTRY["inpainter"], "fake", Fake)
    monkeypatch.setitem(base._REGISTRY["inpainter"], "plain", NoDevice)
    pc = get_preset().perception
    made = _backend(pc, "inpainter", "fake", 7, "cuda:1")
    assert (made.seed, made.device) == (7, "cuda:1")
    assert _backend(pc, "inpainter", "plain", 7, "cuda:1").seed == 7


def test_gpu_share_of_ray_tasks():
    assert gpu_share(1, 4) == 0.25
    assert gpu_share(8, 4) == 1.0
    assert gpu_share(2, 3) == pytest.approx(2 / 3)
    with pytest.raises(InvalidInputError, match="no GPU"):
        gpu_share(0, 2)


# -- the optimizer on a device ------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny():
    from easyhoi.testing.optim_scenes import make_scene

    scene = make_scene("box", size=SIZE, rot_noise=0.05, trans_noise=0.02, depth_noise=0.05,
                       pose_noise=0.03)  # fmt: skip
    over = {"camera.max_iters": 6, "contact.max_iters": 8, "contact.register_at": [2, 5],
            "refine.max_iters": 4}  # fmt: skip
    cfg = with_overrides(replace(get_preset("fast").optim, render_size=SIZE), over)
    return scene, cfg


@pytest.fixture(scope="module")
def cpu_result(tiny, hand):
    scene, cfg = tiny
    return optimize(scene.inp, cfg, hand_model=hand, device="cpu")


def test_the_optimizer_creates_every_tensor_on_the_runs_device(tiny, hand, cpu_result):
    """A tensor created without naming its device lands on the default device: made "meta"
    here, any such tensor meets the run's CPU tensors and the run fails. On a GPU the same
    omission would put a tensor on the CPU next to CUDA tensors."""
    scene, cfg = tiny
    ref = cpu_result
    torch.set_default_device("meta")
    try:
        out = optimize(scene.inp, cfg, hand_model=hand, device="cpu")
    finally:
        torch.set_default_device(None)
    np.testing.assert_array_equal(out.hand_vertices, ref.hand_vertices)
    assert out.camera.K.device.type == "cpu" and out.hand_params.pose.device.type == "cpu"


def _assert_same_result(a, b, extent: float):
    assert [s.name for s in a.stages] == [s.name for s in b.stages]
    dv = np.abs(a.hand_vertices - b.hand_vertices).max()
    assert dv <= VERTEX_TOL * extent, dv
    ka, kb = a.camera.K.cpu().double(), b.camera.K.cpu().double()
    assert float(((ka - kb).abs() / ka.abs().clamp(min=1.0)).max()) <= CAMERA_TOL
    assert float((a.camera.R.cpu() - b.camera.R.cpu()).abs().max()) <= CAMERA_TOL
    ta, tb = a.camera.t.cpu().double(), b.camera.t.cpu().double()
    assert float((ta - tb).norm() / ta.norm()) <= CAMERA_TOL
    assert abs(a.metric_scale / b.metric_scale - 1.0) <= SCALE_TOL
    assert a.plausibility["in_contact"] == b.plausibility["in_contact"]
    for key, tol in METRIC_TOL.items():
        x, y = a.plausibility[key], b.plausibility[key]
        assert (x is None) == (y is None), key
        if x is not None:
            assert abs(x - y) <= tol, (key, x, y)


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=CUDA)])
def test_same_input_and_seed_same_result_on_another_device(tiny, hand, cpu_result, device):
    """The fast preset on "cpu" (numba kernels) vs ``device`` with the torch kernels."""
    scene, cfg = tiny
    extent = float(np.ptp(np.asarray(scene.inp.object_mesh.vertices), axis=0).max())
    ref = cpu_result
    soft.set_backend("torch")
    try:
        out = optimize(scene.inp, cfg, hand_model=hand, device=device)
    finally:
        soft.set_backend("auto")
    assert out.camera.K.device.type == "cpu"  # results come back on the CPU
    _assert_same_result(out, ref, extent)


class _FakeRay:
    """The part of the Ray API the executor uses; records the resources tasks ask for."""

    class exceptions:  # noqa: N801 - mirrors ray.exceptions
        class RayError(Exception):
            pass

        class WorkerCrashedError(RayError):
            pass

    def __init__(self, gpus: float):
        self.gpus, self.asked, self.refs = gpus, None, {}

    def is_initialized(self):
        return True  # Ray already running: the executor neither starts nor stops it

    def cluster_resources(self):
        return {"CPU": 4.0, "GPU": self.gpus} if self.gpus else {"CPU": 4.0}

    def remote(self, **resources):
        self.asked = resources

        def submit(worker, task, threads):
            ref = len(self.refs)
            self.refs[ref] = task
            return ref

        return lambda fn: type("Remote", (), {"remote": staticmethod(submit)})

    def put(self, obj):
        return obj

    def wait(self, waiting, num_returns=1):
        return waiting[:num_returns], waiting[num_returns:]

    def get(self, ref):
        from easyhoi.distributed import TaskResult

        return TaskResult(self.refs[ref].key, "ok", 0.0)


class _Worker:
    def __init__(self, device):
        self.device = device

    def __call__(self, task):
        return None


@pytest.mark.parametrize(("device", "gpus", "share"), [("cuda", 1, 0.5), ("cuda:0", 4, 1.0),
                                                       ("cpu", 1, 0)])  # fmt: skip
def test_ray_tasks_ask_for_a_gpu_share_on_cuda(device, gpus, share):
    from easyhoi.distributed import Task, _iter_ray

    ray = _FakeRay(gpus)
    tasks = [Task(f"p{i}.png", f"p{i}.png", f"out/p{i}", i) for i in range(3)]
    done = list(_iter_ray(ray, tasks, _Worker(device), 2, 1, None))
    assert sorted(r.key for r in done) == ["p0.png", "p1.png", "p2.png"]
    assert ray.asked == {"num_cpus": 1, "num_gpus": share, "max_retries": 1}
    with pytest.raises(InvalidInputError, match="no GPU"):
        list(_iter_ray(_FakeRay(0), tasks, _Worker("cuda"), 2, 1, None))


def test_hand_model_on_another_device_is_a_moved_copy(hand):
    assert hand.on_device("cpu") is hand
    moved = hand.on_device("meta")  # a device every torch build has
    assert moved is not hand and moved.faces.device.type == "meta"
    assert moved.regions.contact_vertices.device.type == "meta"
    assert hand.faces.device.type == "cpu" and hand.regions.vertex_part.device.type == "cpu"
    assert moved.faces.shape == hand.faces.shape


def test_auto_keeps_the_optimizer_on_the_cpu(monkeypatch, hand):
    # the optimizer is slower on a GPU than with the CPU's numba kernels (docs/gpu.md): "auto"
    # puts the large models there and the optimizer on the CPU; a named device takes both
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    cfg = get_preset("fast")
    run = resolve_run(cfg, hand_model=hand, device="auto")
    assert (run.device, run.optim_device) == ("cuda", "cpu")
    assert run.with_seed(3).optim_device == "cpu"
    assert resolve_run(cfg, hand_model=hand, device="cuda").optim_device == "cuda"
    assert resolve_run(cfg, hand_model=hand, device="cuda:1").optim_device == "cuda:1"
    assert resolve_run(replace(cfg, device="cuda:1"), hand_model=hand).optim_device == "cuda:1"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_run(cfg, hand_model=hand).optim_device == "cpu"
