import os
import secrets

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# Ray's token authentication, one token for every Ray the tests start (read when Ray is imported)
os.environ.setdefault("RAY_AUTH_MODE", "token")
os.environ.setdefault("RAY_AUTH_TOKEN", secrets.token_hex(16))
from recon import kernels  # noqa: E402

kernels.pin()  # before torch loads: the committed check slices are recorded likewise

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(1)

DATA = Path(__file__).resolve().parent / "data"
MOCAP_CLIPS = DATA / "mocap"  # short raw excerpts: the tests never read ../shared


@pytest.fixture(scope="session")
def body():
    from recon.body import default_body

    return default_body()


@pytest.fixture(scope="session")
def mocap():
    from recon.poses.mocap import MocapPoses

    return MocapPoses.load()
