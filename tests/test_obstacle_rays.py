"""ObstacleRayCaster agrees with MuJoCo's mj_ray on boxes, cylinders and convex meshes."""

import mujoco
import numpy as np
import pytest
import trimesh

from legoh_rl.envs.native import load_library
from legoh_rl.envs.obstacle_rays import ObstacleRayCaster

# every cast test runs on the numpy path and on the native kernel (where it builds), 1 and 2 threads
IMPLS = [("numpy", 1)] + ([("native", 1), ("native", 2)] if load_library() is not None else [])


@pytest.fixture(params=IMPLS, ids=[f"{i}-{t}" for i, t in IMPLS])
def impl(request):
    return request.param


def _caster(model, impl, **kw) -> ObstacleRayCaster:
    caster = ObstacleRayCaster.from_model(model, **kw)
    caster.native = impl[0] == "native"
    threads = impl[1]
    plain_cast = caster.cast
    caster.cast = lambda o, d, t: plain_cast(o, d, t, threads=threads)
    return caster


GROUPS = np.array([0, 1, 0, 0, 0, 0], dtype=np.uint8)


def _hull(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A convex hull of random points, off-centre and anisotropic (the mesh frame is not its COM)."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(40, 3)) * np.array([0.5, 0.3, 0.2]) + np.array([0.3, -0.2, 0.1])
    hull = trimesh.convex.convex_hull(pts)
    return np.asarray(hull.vertices), np.asarray(hull.faces)


def _floats(a: np.ndarray) -> str:
    return " ".join(f"{x:.9g}" for x in np.asarray(a).ravel())


def _model(extra: str = "", asset: str = "") -> mujoco.MjModel:
    verts, faces = _hull(0)
    xml = f"""
    <mujoco>
      <asset>
        <mesh name="rock" vertex="{_floats(verts)}" face="{_floats(faces)}"/>
        <mesh name="tet" vertex="0 0 0  0.6 0 0  0 0.5 0  0 0 0.4"/>
        {asset}
      </asset>
      <worldbody>
        <geom name="floor" type="plane" size="10 10 0.1" group="0"/>
        <geom name="box" type="box" size="0.4 0.25 0.15" pos="1 0.5 0.4" euler="20 35 -50" group="1"/>
        <geom name="post" type="cylinder" size="0.15 0.6" pos="-1 0.8 0.6" group="1"/>
        <geom name="log" type="cylinder" size="0.12 0.7" pos="0.2 -1.1 0.3" euler="90 30 10" group="1"/>
        <geom name="rock" type="mesh" mesh="rock" pos="-0.9 -0.7 0.5" euler="15 -25 70" group="1"/>
        <geom name="tet" type="mesh" mesh="tet" pos="1.2 -0.6 0.1" euler="0 0 40" group="1"/>
        <geom name="hidden" type="box" size="0.3 0.3 0.3" pos="0 2 0.3" group="1" rgba="1 1 1 0"/>
        {extra}
      </worldbody>
    </mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


def _mj_ray(model, data, o, d):
    gid = np.zeros(1, dtype=np.int32)
    return np.array([mujoco.mj_ray(model, data, o[i], d[i], GROUPS, 1, -1, gid) for i in range(len(o))])


def _assert_same_hits(got, want):
    """Caster distances ``got`` agree with ``want`` (``inf`` = miss): same hits, within 1e-6 m."""
    hit = np.isfinite(want)
    np.testing.assert_array_equal(np.isfinite(got), hit)
    np.testing.assert_allclose(got[hit], want[hit], rtol=0, atol=1e-6)


def _random_rays(caster: ObstacleRayCaster, n: int, seed: int):
    """Origins outside every geom's bounding sphere; half the rays aimed near a geom."""
    rng = np.random.default_rng(seed)
    o = rng.uniform([-2.5, -2.5, 0.0], [2.5, 2.5, 1.5], size=(4 * n, 3))
    gap = np.linalg.norm(o[:, None, :] - caster.pos[None], axis=-1) - caster.rbound[None]
    o = o[(gap > 1e-3).all(axis=1)][:n]
    d = rng.normal(size=(n, 3))
    aimed = rng.random(n) < 0.5
    target = caster.pos[rng.integers(caster.num_geoms, size=n)] + rng.normal(scale=0.2, size=(n, 3))
    d[aimed] = (target - o)[aimed]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d


def test_from_model_reads_group_one():
    m = _model()
    c = ObstacleRayCaster.from_model(m)
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(g)) for g in c.geom_ids]
    assert names == ["box", "post", "log", "rock", "tet"]  # no floor (group 0), no invisible box


def test_cast_matches_mj_ray(impl):
    m = _model()
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    caster = _caster(m, impl)
    o, d = _random_rays(caster, 4000, seed=1)
    ref = _mj_ray(m, data, o, d)
    assert 0.3 < np.mean(ref >= 0.0) < 0.9  # plenty of hits and misses
    # unlimited range: every mj_ray hit
    got = caster.cast(o, d, np.full(len(o), np.inf))
    _assert_same_hits(got, np.where(ref >= 0.0, ref, np.inf))
    # random range: hits beyond t_max are misses
    rng = np.random.default_rng(2)
    t_max = rng.uniform(0.0, 4.0, size=len(o))
    got = caster.cast(o, d, t_max)
    want = np.where((ref >= 0.0) & (ref <= t_max), ref, np.inf)
    _assert_same_hits(got, want)
    # every geom kind is hit somewhere
    gid = np.zeros(1, dtype=np.int32)
    hit_geoms = set()
    for i in np.flatnonzero(ref >= 0.0)[:2000]:
        mujoco.mj_ray(m, data, o[i], d[i], GROUPS, 1, -1, gid)
        hit_geoms.add(int(gid[0]))
    assert hit_geoms == set(caster.geom_ids.tolist())


def test_candidates_are_exactly_the_bounding_sphere_hits():
    # the block pre-cull is conservative: the pairs equal a brute-force (M, G) sphere test,
    # whatever the ray order (shuffled rays make the blocks incoherent)
    caster = ObstacleRayCaster.from_model(_model())
    o, d = _random_rays(caster, 3000, seed=6)
    t_max = np.random.default_rng(7).uniform(0.0, 3.0, size=len(o))
    t_max[::10] = np.inf
    oc = caster.pos[None] - o[:, None]  # (M, G, 3)
    ts = np.clip(np.einsum("mgi,mi->mg", oc, d), 0.0, t_max[:, None])
    dist = np.linalg.norm(oc - ts[..., None] * d[:, None], axis=-1)
    want = set(zip(*np.nonzero(dist <= caster.rbound[None]), strict=True))
    for order in (np.arange(len(o)), np.random.default_rng(8).permutation(len(o))):
        r, g = caster.candidates(o[order], d[order], t_max[order])
        assert set(zip(order[r], g, strict=True)) == want


def test_non_unit_directions_measure_in_units_of_the_direction(impl):
    m = _model()
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    caster = _caster(m, impl)
    o, d = _random_rays(caster, 500, seed=3)
    d = d * np.random.default_rng(4).uniform(0.2, 3.0, size=(len(d), 1))
    ref = _mj_ray(m, data, o, d)
    got = caster.cast(o, d, np.full(len(o), np.inf))
    _assert_same_hits(got, np.where(ref >= 0.0, ref, np.inf))


def test_origin_inside_reports_the_exit_like_mj_ray(impl):
    m = _model()
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    caster = _caster(m, impl)
    rng = np.random.default_rng(5)
    # points near each geom's frame origin (inside every one of these geoms), random directions
    o = np.repeat(caster.pos, 50, axis=0) + rng.normal(scale=0.02, size=(50 * caster.num_geoms, 3))
    d = rng.normal(size=o.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ref = _mj_ray(m, data, o, d)
    got = caster.cast(o, d, np.full(len(o), np.inf))
    assert (ref > 0.0).all()
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6)


def test_convex_mesh_faces_match_hull():
    # the planes of the rock's faces bound exactly its hull: every vertex on or inside
    m = _model()
    caster = ObstacleRayCaster.from_model(m)
    k = int(np.flatnonzero(caster.geom_type == mujoco.mjtGeom.mjGEOM_MESH)[0])
    mesh = int(m.geom_dataid[caster.geom_ids[k]])
    verts = m.mesh_vert[m.mesh_vertadr[mesh] : m.mesh_vertadr[mesh] + m.mesh_vertnum[mesh]]
    planes = caster._planes[caster._mesh_index[k]]
    assert (verts @ planes[:, :3].T - planes[:, 3] <= 1e-6).all()


def test_unsupported_type_raises():
    m = _model('<geom name="egg" type="ellipsoid" size="0.2 0.3 0.4" pos="0 0 2" group="1"/>')
    with pytest.raises(ValueError, match=r"geom \d+ \(egg\).*ellipsoid"):
        ObstacleRayCaster.from_model(m)
    # other groups are not read
    ObstacleRayCaster.from_model(_model('<geom type="ellipsoid" size="0.2 0.3 0.4" pos="0 0 2" group="2"/>'))


def test_non_convex_mesh_raises():
    # an L-shaped prism: concave
    v = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [1, 1, 0], [1, 2, 0], [0, 2, 0]], float)
    verts = np.concatenate([v, v + [0, 0, 1]])
    faces = []
    for a, b, c in [(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 5)]:
        faces += [(a, c, b), (a + 6, b + 6, c + 6)]
    for i in range(6):
        j = (i + 1) % 6
        faces += [(i, j, j + 6), (i, j + 6, i + 6)]
    asset = f'<mesh name="ell" vertex="{_floats(verts)}" face="{_floats(np.array(faces))}"/>'
    m = _model('<geom name="ell" type="mesh" mesh="ell" pos="0 2 2" group="1"/>', asset)
    with pytest.raises(ValueError, match=r"\(ell\): mesh is not convex"):
        ObstacleRayCaster.from_model(m)


def test_shapes_and_empty(impl):
    caster = _caster(_model(), impl)
    out = caster.cast(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    assert out.shape == (0,) and out.dtype == np.float64
    # far from everything, pointing away: all misses
    o = np.tile([0.0, 0.0, 5.0], (7, 1))
    out = caster.cast(o, np.tile([0.0, 0.0, 1.0], (7, 1)), np.full(7, 10.0))
    assert out.shape == (7,) and np.isinf(out).all()
    # a group with no geoms: everything misses
    empty = _caster(_model(), impl, group=4)
    assert empty.num_geoms == 0
    assert np.isinf(empty.cast(o, -o, np.full(7, 10.0))).all()
