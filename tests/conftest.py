import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(1)

from recon import paths  # noqa: E402

MOCAP = paths.shared_dir() / "data" / "mocap"
needs_mocap = pytest.mark.skipif(not (MOCAP / "metadata" / "clips.csv").exists(),
                                 reason=f"mocap data not found at {MOCAP}")


@pytest.fixture(scope="session")
def body():
    from recon.body import default_body

    return default_body()


@pytest.fixture(scope="session")
def mocap():
    from recon.poses.mocap import MocapPoses

    if not (MOCAP / "metadata" / "clips.csv").exists() and not (paths.cache_dir() / "mocap-anny-v1.npz").exists():
        pytest.skip("no mocap data and no mocap cache")
    return MocapPoses.load()
