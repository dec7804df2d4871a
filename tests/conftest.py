import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# The same float kernels on every x86 machine (set before torch loads): the committed check slices
# (tests/test_results.py) hold the backbone's outputs, which differ in the last bits between AVX2 and
# AVX-512 kernels, and its crop search can turn such bits into another crop. Record them likewise.
for _var, _isa in (("ATEN_CPU_CAPABILITY", "avx2"), ("ONEDNN_MAX_CPU_ISA", "AVX2"), ("MKL_CBWR", "AVX2")):
    os.environ.setdefault(_var, _isa)

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
