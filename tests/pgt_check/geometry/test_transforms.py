import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pgt_check.geometry.transforms import (
    QuaternionError,
    apply_rigid,
    axis_angle_to_rotmat,
    invert_rigid,
    make_rigid,
    quat_to_rotmat,
    rotation_angle_deg,
    rotmat_to_quat,
)

quats = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1
)


@settings(max_examples=200, deadline=None)
@given(quats)
def test_quaternion_round_trip(q):
    q = np.array(q) / np.linalg.norm(q)
    r = quat_to_rotmat(q)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    q2 = rotmat_to_quat(r)
    # q and -q are the same rotation
    assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-9


def test_near_antipodal_quaternions_give_same_rotation():
    q = np.array([1e-9, 1.0, 0.0, 0.0])
    np.testing.assert_allclose(quat_to_rotmat(q), quat_to_rotmat(-q), atol=1e-12)


def test_quaternion_norm_tolerance():
    quat_to_rotmat(np.array([1.005, 0, 0, 0]))  # normalised with a debug log
    with pytest.raises(QuaternionError, match="norm"):
        quat_to_rotmat(np.array([1.5, 0, 0, 0]))
    with pytest.raises(QuaternionError, match="finite"):
        quat_to_rotmat(np.array([np.nan, 0, 0, 0]))


def test_invert_and_apply():
    rng = np.random.default_rng(0)
    r = axis_angle_to_rotmat(rng.normal(size=3), 37.0)
    a_from_b = make_rigid(r, [1e6, -2e5, 3.0])
    p = rng.normal(size=(5, 3))
    back = apply_rigid(invert_rigid(a_from_b), apply_rigid(a_from_b, p))
    np.testing.assert_allclose(back, p, atol=1e-8)
    assert rotation_angle_deg(r) == pytest.approx(37.0)
    assert rotation_angle_deg(np.eye(3)) == 0.0


def test_transforms_do_not_import_types():
    """No import circle: geometry.transforms needs only pgt_check.common.checks, and types imports it
    at the top (check_shape stays importable from pgt_check.types)."""
    import subprocess
    import sys

    code = (
        "import sys; import pgt_check.geometry.transforms; "
        "assert 'pgt_check.types' not in sys.modules, 'transforms imported types'; "
        "from pgt_check.types import check_shape; "
        "from pgt_check.common.checks import check_shape as c; assert check_shape is c"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
