"""rigcal.core.geometry against GTSAM (an independent implementation) and against its own
definitions: look/axes frames, quaternions, rotation vectors, pose inverses."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.core import geometry as geo

try:
    import gtsam
except ImportError:  # the [test] extra installs it where a wheel works with numpy 2 (Python >= 3.11)
    gtsam = None
# gtsam 4.2, the last wheel for Python 3.10, is built against numpy 1 and crashes with the
# numpy 2 that OpenCV 5 needs: there the cross-checks against gtsam skip, the rest runs.
needs_gtsam = pytest.mark.skipif(gtsam is None, reason="gtsam is not installed (no wheel for this Python and numpy 2)")

N_RANDOM = 1000


def random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3, 3) rotations, uniform on SO(3) (unit quaternions from a normal sample)."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.array([geo.R_from_quat(qi) for qi in q])


@pytest.fixture(scope="module")
def poses_and_points():
    rng = np.random.default_rng(20240601)
    Rs = random_rotations(rng, N_RANDOM)
    ts = rng.uniform(-50, 50, size=(N_RANDOM, 3))
    ps = rng.uniform(-100, 100, size=(N_RANDOM, 3))
    Ts = np.array([geo.make_T(R, t) for R, t in zip(Rs, ts)])
    gposes = [gtsam.Pose3(gtsam.Rot3(R), gtsam.Point3(*t)) for R, t in zip(Rs, ts)]
    return Ts, ps, gposes


@needs_gtsam
def test_transform_matches_gtsam_transform_from(poses_and_points):
    Ts, ps, gposes = poses_and_points
    ours = np.array([geo.transform(T, p) for T, p in zip(Ts, ps)])
    theirs = np.array([g.transformFrom(gtsam.Point3(*p)) for g, p in zip(gposes, ps)])
    np.testing.assert_allclose(ours, theirs, atol=1e-9, rtol=0)


@needs_gtsam
def test_inverse_transform_matches_gtsam_transform_to(poses_and_points):
    Ts, ps, gposes = poses_and_points
    ours = np.array([geo.transform(geo.inv_T(T), p) for T, p in zip(Ts, ps)])
    theirs = np.array([g.transformTo(gtsam.Point3(*p)) for g, p in zip(gposes, ps)])
    np.testing.assert_allclose(ours, theirs, atol=1e-9, rtol=0)
    # inv_T works on a stack of poses too, and agrees with gtsam's inverse
    np.testing.assert_allclose(geo.inv_T(Ts), np.array([g.inverse().matrix() for g in gposes]), atol=1e-9)


@needs_gtsam
def test_composition_matches_gtsam_compose(poses_and_points):
    Ts, _, gposes = poses_and_points
    ours = Ts[:-1] @ Ts[1:]
    theirs = np.array([a.compose(b).matrix() for a, b in zip(gposes[:-1], gposes[1:])])
    np.testing.assert_allclose(ours, theirs, atol=1e-9, rtol=0)


@needs_gtsam
def test_transform_of_many_points_at_once(poses_and_points):
    Ts, ps, gposes = poses_and_points
    ours = geo.transform(Ts[7], ps)
    theirs = gposes[7].transformFrom(ps.T).T  # gtsam takes (3, N)
    np.testing.assert_allclose(ours, theirs, atol=1e-9, rtol=0)


@needs_gtsam
def test_quaternion_matches_gtsam(poses_and_points):
    Ts, _, gposes = poses_and_points
    for T, g in zip(Ts[:200], gposes[:200]):
        q = geo.quat_from_R(T[:3, :3])
        gq = g.rotation().toQuaternion()
        theirs = np.array([gq.w(), gq.x(), gq.y(), gq.z()])
        theirs *= np.sign(theirs[0]) or 1.0  # ours is normalised to w >= 0
        np.testing.assert_allclose(q, theirs, atol=1e-9)
        np.testing.assert_allclose(geo.R_from_quat(q), gtsam.Rot3.Quaternion(*q).matrix(), atol=1e-12)


@needs_gtsam
def test_rotation_vector_matches_gtsam_expmap_logmap():
    rng = np.random.default_rng(7)
    axes = rng.normal(size=(300, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0, np.pi - 1e-6, size=300)
    r = axes * angles[:, None]
    Rs = geo.R_from_rotvec(r)  # vectorised over the stack
    for ri, Ri in zip(r, Rs):
        np.testing.assert_allclose(Ri, gtsam.Rot3.Expmap(ri).matrix(), atol=1e-12)
        np.testing.assert_allclose(geo.rotvec_from_R(Ri), gtsam.Rot3.Logmap(gtsam.Rot3(Ri)), atol=1e-9)


# ----------------------------------------------------------------------------- look / axes


LOOK_DIRECTION = {"forward": "F", "backward": "-F", "left": "L", "right": "-L", "up": "U", "down": "-U"}


@pytest.mark.parametrize("look", sorted(LOOK_DIRECTION))
def test_look_frames(look):
    R = geo.R_from_look(look)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0)  # right-handed
    # z (into the scene) points along the named body direction
    np.testing.assert_array_equal(R[:, 2], geo.token_vector(LOOK_DIRECTION[look], geo.BODY_AXES))
    # the top of the image (camera -y) points up for horizontal looks, to the nose for up/down
    top = "F" if look in ("up", "down") else "U"
    np.testing.assert_array_equal(-R[:, 1], geo.token_vector(top, geo.BODY_AXES))
    # and the frame is exactly the `axes` form of rig-yaml.md
    np.testing.assert_array_equal(R, geo.R_from_axes(geo.LOOK_AXES[look]))


@needs_gtsam
def test_look_forward_is_the_textbook_rot3():
    # GTSAM's Rot3(-L, -U, F) in FLU: columns are the camera axes in body terms
    L, U, F = np.array([0.0, 1, 0]), np.array([0.0, 0, 1]), np.array([1.0, 0, 0])
    np.testing.assert_array_equal(geo.R_from_look("forward"), gtsam.Rot3(-L, -U, F).matrix())


def test_axes_accept_vectors_and_normalise_them():
    s = np.sqrt(0.5)
    R = geo.R_from_axes([[s, -s, 0], [0, 0, -1], [2 * s, 2 * s, 0]])  # yaw 45 deg, z given with length 2
    np.testing.assert_allclose(R[:, 2], [s, s, 0], atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0)


@pytest.mark.parametrize("axes, why", [
    (["-L", "-U", "L"], "orthonormal"),            # two parallel axes
    (["L", "-U", "F"], "right-handed"),            # a mirror image
    ([[1, 0, 0], [0.1, 1, 0], [0, 0, 1]], "orthonormal"),  # skewed by 0.1 rad
    (["F", "L"], "three axes"),
    (["F", "L", "Q"], "not one of"),
    (["F", "L", [0, 0, 0]], "zero vector"),
    (["F", "L", [0, 0, float("nan")]], "finite"),
])
def test_axes_rejects_frames_that_are_not_rotations(axes, why):
    with pytest.raises(ValueError, match=why):
        geo.R_from_axes(axes)


def test_axes_tolerance_is_1e6_after_normalising():
    geo.R_from_axes([[1, 0, 0], [0, 1, 5e-7], [0, 0, 1]])  # inside the tolerance
    with pytest.raises(ValueError):
        geo.R_from_axes([[1, 0, 0], [0, 1, 5e-6], [0, 0, 1]])


# ----------------------------------------------------------------------------- quaternions, rotvecs


def test_quaternion_round_trips():
    rng = np.random.default_rng(11)
    for R in random_rotations(rng, 500):
        q = geo.quat_from_R(R)
        assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1.0)
        np.testing.assert_allclose(geo.R_from_quat(q), R, atol=1e-12)
    for q in rng.normal(size=(500, 4)):
        q /= np.linalg.norm(q)
        q *= np.sign(q[0])
        np.testing.assert_allclose(geo.quat_from_R(geo.R_from_quat(q)), q, atol=1e-12)


def test_quaternion_is_w_first_hamilton():
    # 90 degrees about body U: F -> L
    q = [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]
    np.testing.assert_allclose(geo.R_from_quat(q) @ [1, 0, 0], [0, 1, 0], atol=1e-15)


@pytest.mark.parametrize("q", [[1, 0, 0, 0.01], [0.5, 0.5, 0.5, 0.4], [0, 0, 0, 0], [1, 0, 0], [np.nan, 0, 0, 1]])
def test_quaternion_must_be_unit_and_finite(q):
    with pytest.raises(ValueError):
        geo.R_from_quat(q)


@pytest.mark.parametrize("angle", [0.0, 1e-15, 1e-9, 1e-6, 1e-3, 1.0, np.pi / 2, np.pi - 1e-3, np.pi - 1e-6,
                                   np.pi - 1e-9])
def test_rotation_vector_round_trips_near_zero_and_pi(angle):
    rng = np.random.default_rng(int(angle * 1e6) % 2**32)
    for axis in rng.normal(size=(20, 3)):
        axis /= np.linalg.norm(axis)
        r = axis * angle
        R = geo.R_from_rotvec(r)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
        np.testing.assert_allclose(geo.rotvec_from_R(R), r, atol=1e-9, rtol=0)
        # small angles keep their relative precision too (first-order terms are exact)
        if 0 < angle < 1e-3:
            np.testing.assert_allclose(geo.rotvec_from_R(R), r, rtol=1e-6)


def test_vectorised_rotation_vectors_match_the_single_ones():
    """rotvecs_from_R (batched, used by the hand-eye start) against rotvec_from_R, over
    random rotations and the angles where the axis part vanishes (0, and pi)."""
    rng = np.random.default_rng(17)
    axes = rng.normal(size=(60, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0, np.pi, 40), [0.0, 1e-12, 1e-6, np.pi - 1e-6, np.pi - 0.1, np.pi - 0.2,
                                                          np.pi - 1e-3, np.pi, 1.0, 2.0, 3.0, 0.5, 1e-3, 0.1, 2.9,
                                                          3.1, 1.5, 2.5, 0.2, 1e-9]])
    Rs = geo.R_from_rotvec(axes * angles[:, None])
    single = np.array([geo.rotvec_from_R(R) for R in Rs])
    batched = geo.rotvecs_from_R(Rs)
    # at exactly pi the axis sign is arbitrary: compare the rotations there
    np.testing.assert_allclose(geo.R_from_rotvec(batched), Rs, atol=1e-12)
    away = angles < np.pi - 1e-9
    np.testing.assert_allclose(batched[away], single[away], atol=1e-9, rtol=0)


def test_rotation_vector_at_exactly_pi_gives_the_same_rotation():
    for axis in np.eye(3):
        R = geo.R_from_rotvec(np.pi * axis)
        r = geo.rotvec_from_R(R)
        assert np.linalg.norm(r) == pytest.approx(np.pi)
        np.testing.assert_allclose(geo.R_from_rotvec(r), R, atol=1e-12)  # +-axis: the same rotation


def test_rt_round_trip_and_stacks():
    rng = np.random.default_rng(3)
    rt = np.column_stack([rng.normal(size=(50, 3)), rng.uniform(-5, 5, size=(50, 3))])
    Ts = geo.T_from_rt(rt)
    assert Ts.shape == (50, 4, 4)
    back = np.array([geo.rt_from_T(T) for T in Ts])
    # rotation vectors longer than pi come back as their shorter equivalent: compare poses
    np.testing.assert_allclose(geo.T_from_rt(back), Ts, atol=1e-12)


def test_inv_T_composes_to_identity():
    rng = np.random.default_rng(5)
    for R, t in zip(random_rotations(rng, 100), rng.normal(size=(100, 3)) * 10):
        T = geo.make_T(R, t)
        np.testing.assert_allclose(T @ geo.inv_T(T), np.eye(4), atol=1e-12)
        np.testing.assert_allclose(geo.inv_T(geo.inv_T(T)), T, atol=1e-12)


def test_check_rotation_rejects_reflections_and_skew():
    with pytest.raises(ValueError, match="reflection"):
        geo.check_rotation(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="orthonormal"):
        geo.check_rotation(np.eye(3) * 1.01)


# ----------------------------------------------------------------------------- navigation frame


@pytest.mark.parametrize("heading, axes", [(0, ["N", "-E", "U"]), (90, ["E", "N", "U"]),
                                           (180, ["-N", "E", "U"]), (270, ["-E", "-N", "U"])])
def test_heading_matches_axes(heading, axes):
    T_h = geo.T_nav_body_from_heading([1, 2, 3], heading)
    T_a = geo.T_nav_body_from_axes([1, 2, 3], axes)
    np.testing.assert_allclose(T_h, T_a, atol=1e-15)


def test_heading_is_clockwise_from_north():
    # flying north-east (45 deg): the nose points at +E +N
    T = geo.T_nav_body_from_heading([0, 0, 0], 45.0)
    np.testing.assert_allclose(T[:3, 0], [np.sqrt(0.5), np.sqrt(0.5), 0], atol=1e-15)
    np.testing.assert_allclose(T[:3, 2], [0, 0, 1])


@pytest.mark.parametrize("n", [1, 2])
def test_robust_mean_pose_shortcut_for_one_or_two_equals_the_iteration(n):
    """With one or two poses the reweighting cannot change anything (two residual angles
    are equal); the shortcut must give what the iteration gives."""
    rng = np.random.default_rng(n)
    for _ in range(20):
        Ts = np.array([geo.make_T(geo.R_from_rotvec(rng.normal(0, 0.3, 3)), rng.normal(0, 1, 3)) for _ in range(n)])
        R, w = geo.mean_rotation(Ts[:, :3, :3]), np.ones(n)
        for _ in range(3):
            ang = geo.rotation_angles(np.einsum("ji,njk->nik", R, Ts[:, :3, :3]))
            scale = 3.0 * max(np.median(ang), 1e-4)
            w = 1.0 / (1.0 + (ang / scale) ** 2)
            w[ang > 3 * scale] = 0.0
            R = geo.mean_rotation(Ts[:, :3, :3], w)
        expected = geo.make_T(R, np.median(Ts[w > 0, :3, 3], axis=0))
        assert np.allclose(geo.robust_mean_pose(Ts), expected, atol=1e-12)


def test_nearest_rotation_known_answers_and_batches():
    rng = np.random.default_rng(7)
    Rs = random_rotations(rng, 5)
    # a scaled rotation's nearest rotation is itself; so is one with a little symmetric noise
    np.testing.assert_allclose(geo.nearest_rotation(3.0 * Rs[0]), Rs[0], atol=1e-12)
    noisy = Rs + 1e-3 * rng.normal(size=(5, 3, 3))
    got = geo.nearest_rotation(noisy)  # batched (5, 3, 3)
    assert got.shape == (5, 3, 3)
    np.testing.assert_allclose(got @ np.swapaxes(got, 1, 2), np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(got), 1.0, atol=1e-12)
    assert np.abs(got - Rs).max() < 5e-3
    for M, R in zip(noisy, got):  # the batch equals one at a time
        np.testing.assert_allclose(geo.nearest_rotation(M), R, atol=1e-14)
    # a reflection is never returned: the determinant is fixed to +1
    assert np.linalg.det(geo.nearest_rotation(np.diag([1.0, 1.0, -1.0]))) > 0


def test_fit_rigid_to_recovers_a_known_transform_and_is_least_squares():
    """Exact: poses D = T S recover T. Noisy: the fit beats the true T and small perturbations of
    the fit on the cost it minimises (rotation chordal + centred position)."""
    rng = np.random.default_rng(3)
    S = np.array([geo.make_T(geo.R_from_rotvec(rng.normal(0, 1, 3)), rng.normal(0, 0.5, 3)) for _ in range(4)])
    T = geo.make_T(geo.R_from_rotvec([0.3, -1.2, 0.7]), [0.1, 2.0, -0.4])
    np.testing.assert_allclose(geo.fit_rigid_to(S, T @ S), T, atol=1e-12)
    D = np.array([geo.make_T(geo.R_from_rotvec(rng.normal(0, 0.02, 3)) @ P[:3, :3], P[:3, 3] + rng.normal(0, 0.01, 3))
                  for P in T @ S])

    def cost(X):
        Y = X @ S
        return float(np.sum((Y[:, :3, :3] - D[:, :3, :3]) ** 2) + np.sum((Y[:, :3, 3] - D[:, :3, 3]) ** 2))

    fit = geo.fit_rigid_to(S, D)
    assert cost(fit) <= cost(T) + 1e-15
    for _ in range(20):
        nudge = geo.make_T(geo.R_from_rotvec(rng.normal(0, 1e-3, 3)), rng.normal(0, 1e-3, 3))
        assert cost(fit) <= cost(nudge @ fit) + 1e-15


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_robust_mean_poses_batched_equal_robust_mean_pose_exactly(n):
    """The pose graph's batched average gives robust_mean_pose's numbers bit for bit, also
    for groups where an outlier view gets weight 0 and the translation median drops it."""
    rng = np.random.default_rng(n)
    groups = []
    for g in range(60):
        base = geo.make_T(geo.R_from_rotvec(rng.normal(0, 1, 3)), rng.normal(0, 1, 3))
        noise = [geo.make_T(geo.R_from_rotvec(rng.normal(0, 0.002, 3)), rng.normal(0, 0.002, 3)) for _ in range(n)]
        if g % 3 == 0 and n > 2:
            noise[-1] = geo.make_T(geo.R_from_rotvec([0.4, -0.3, 0.2]), [0.5, 0.0, 0.0])  # a gross outlier
        groups.append([base @ T for T in noise])
    Ts = np.array(groups)
    one = np.array([geo.robust_mean_pose(T) for T in Ts])
    assert np.array_equal(geo.robust_mean_poses(Ts), one)
    if n > 3:  # the outliers were rejected: their groups' translations are the inliers' median
        assert np.abs(one[0, :3, 3] - np.median(Ts[0, :-1, :3, 3], axis=0)).max() == 0.0
