"""blender_addon/core/generated_shapes.py: closed, outward, unit-size training shapes with sharp edges,
concavities, thin walls and several parts."""

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from blender_addon.core.generated_shapes import GENERATED_SHAPES, generated_shape  # noqa: E402
from blender_addon.core.procedural import PROCEDURAL_SHAPES, diameter  # noqa: E402
from blender_addon.core.unseen_shapes import UNSEEN_SHAPES  # noqa: E402
from tests.conftest import TOL  # noqa: E402

SEEDS = (0, 1, 5)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("shape", GENERATED_SHAPES)
def test_closed_outward_unit_diameter(shape, seed):
    mesh = generated_shape(shape, seed=seed)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert len(mesh.nondegenerate_faces()) == len(mesh.faces)
    assert len(np.unique(mesh.vertices, axis=0)) == len(mesh.vertices)  # vertices merged
    for part in mesh.split(only_watertight=False):
        assert part.volume > 0, f"{shape}: a part faces inward"
    assert diameter(mesh) == pytest.approx(1.0, abs=TOL.f64)
    v = np.asarray(mesh.vertices)
    np.testing.assert_allclose((v.min(axis=0) + v.max(axis=0)) / 2, 0.0, atol=TOL.f64)
    # Outward: face centres nudged along their normals are outside the solid, against them inside.
    rng = np.random.default_rng(0)
    faces = rng.choice(len(mesh.faces), size=min(60, len(mesh.faces)), replace=False)
    centre = mesh.triangles_center[faces]
    step = 1e-4 * mesh.face_normals[faces]  # well below the thinnest wall (3 % of the diameter)
    np.testing.assert_allclose(winding_number(mesh, centre + step), 0.0, atol=0.02)
    np.testing.assert_allclose(winding_number(mesh, centre - step), 1.0, atol=0.02)


def winding_number(mesh, points):
    """Generalised winding number: the solid angle of the oriented triangles seen from each point / 4 pi
    (Van Oosterom & Strackee 1983), independent of the code under test."""
    a, b, c = (mesh.vertices[mesh.faces[:, k]][None] - points[:, None] for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la
    den += np.einsum("pfi,pfi->pf", c, a) * lb
    return (2 * np.arctan2(det, den)).sum(axis=1) / (4 * np.pi)


@pytest.mark.parametrize("shape", GENERATED_SHAPES)
def test_seed_determinism(shape):
    a, b, c = generated_shape(shape, seed=3), generated_shape(shape, seed=3), generated_shape(shape, seed=4)
    # numpy's SIMD kernels may differ by 1 ulp with the arrays' alignment: equal to rounding.
    np.testing.assert_allclose(a.vertices, b.vertices, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert a.vertices.shape != c.vertices.shape or not np.allclose(a.vertices, c.vertices)


def test_training_shapes_only():
    assert not set(GENERATED_SHAPES) & set(UNSEEN_SHAPES)
    assert not set(GENERATED_SHAPES) & set(PROCEDURAL_SHAPES)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(("shape", "most"), [("extrusion", 0.8), ("bowl", 0.5), ("multipart", 0.6)])
def test_concave_where_claimed(shape, seed, most):
    """Concave shapes fill clearly less than their convex hull (a convex solid fills all of it)."""
    mesh = generated_shape(shape, seed=seed)
    assert mesh.volume < most * mesh.convex_hull.volume


@pytest.mark.parametrize("seed", range(6))
def test_extrusion_has_reflex_edges_and_flat_caps(seed):
    mesh = generated_shape("extrusion", seed=seed)
    # A reflex (concave) edge: the neighbour faces' normals turn inward across it.
    n0 = mesh.face_normals[mesh.face_adjacency[:, 0]]
    v0, v1 = (mesh.vertices[mesh.face_adjacency_unshared[:, k]] for k in (0, 1))
    assert np.sum(np.einsum("ij,ij->i", n0, v1 - v0) > 1e-9) >= 3  # the second face rises above the first
    # Sharp edges: some dihedral angles above 45 degrees (cap to side, concave sides).
    assert np.degrees(mesh.face_adjacency_angles).max() > 45.0
    # Flat caps: the bottom cap lies in one plane.
    z = np.asarray(mesh.vertices)[:, 2]
    assert np.sum(np.abs(z - z.min()) < 1e-12) >= 7


@pytest.mark.parametrize("seed", range(6))
def test_multipart_separate_closed_parts(seed):
    mesh = generated_shape("multipart", seed=seed)
    parts = mesh.split(only_watertight=False)
    assert 2 <= len(parts) <= 4
    assert all(p.is_watertight and p.volume > 0 for p in parts)
    # Not touching: every pair of parts is separated (closest vertices clearly apart).
    for i in range(len(parts)):
        for j in range(i + 1, len(parts)):
            d = np.linalg.norm(parts[i].vertices[:, None] - parts[j].vertices[None], axis=-1).min()
            assert d > 0.01


def test_multipart_parts_parameter():
    assert len(generated_shape("multipart", seed=0, parts=4).split(only_watertight=False)) == 4


@pytest.mark.parametrize("thickness", [0.03, 0.05, 0.08])
def test_bowl_wall_thickness(thickness):
    mesh = generated_shape("bowl", seed=0, thickness=thickness)
    assert wall_thickness(mesh) == pytest.approx(thickness, rel=0.02)


@pytest.mark.parametrize("seed", range(6))
def test_bowl_random_thickness_in_range(seed):
    assert 0.03 * 0.98 < wall_thickness(generated_shape("bowl", seed=seed)) < 0.08 * 1.02


def wall_thickness(mesh):
    """Median distance along rays cast inward from random faces to where they leave the solid.

    The median ignores the rim band (2 % of the faces), whose rays run along the wall, not across.
    """
    rng = np.random.default_rng(1)
    faces = rng.choice(len(mesh.faces), size=41, replace=False)
    normal = mesh.face_normals[faces]
    return float(np.median(first_hit(mesh, mesh.triangles_center[faces] - 1e-9 * normal, -normal)))


def first_hit(mesh, origins, directions):
    """Distance along each ray to the nearest triangle (Moller-Trumbore), inf without a hit."""
    tri = mesh.triangles[None]  # (1, F, 3, 3)
    e1, e2 = tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]
    d = directions[:, None]
    p = np.cross(d, e2)
    det = np.einsum("rfi,rfi->rf", np.broadcast_to(e1, p.shape), p)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = origins[:, None] - tri[..., 0, :]
        u = np.einsum("rfi,rfi->rf", s, p) / det
        q = np.cross(s, e1)
        v = np.einsum("rfi,rfi->rf", np.broadcast_to(d, q.shape), q) / det
        t = np.einsum("rfi,rfi->rf", np.broadcast_to(e2, q.shape), q) / det
    hit = (np.abs(det) > 1e-15) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-7)
    return np.where(hit, t, np.inf).min(axis=1)


@pytest.mark.parametrize("seed", range(6))
def test_heightfield_slab_flat_bottom_vertical_sides(seed):
    mesh = generated_shape("heightfield_slab", seed=seed)
    v = np.asarray(mesh.vertices)
    n = mesh.face_normals
    # Flat bottom: every downward face lies in the plane z = min z.
    down = n[:, 2] < -0.5
    np.testing.assert_allclose(n[down], [[0.0, 0.0, -1.0]] * int(down.sum()), atol=TOL.f64)
    np.testing.assert_allclose(v[mesh.faces[down]][..., 2], v[:, 2].min(), atol=TOL.f64)
    # Vertical sides: horizontal normals along x or y, with 90-degree edges to the bottom.
    side = np.abs(n[:, 2]) < 1e-12
    assert side.sum() >= 4 * 48 and np.allclose(np.sort(np.abs(n[side][:, :2]), axis=1)[:, 0], 0.0, atol=TOL.f64)
    pairs = mesh.face_adjacency
    bottom_edge = (down[pairs[:, 0]] & side[pairs[:, 1]]) | (side[pairs[:, 0]] & down[pairs[:, 1]])
    assert bottom_edge.sum() == 4 * 48
    np.testing.assert_allclose(np.degrees(mesh.face_adjacency_angles[bottom_edge]), 90.0, atol=1e-9)
    # A smooth, non-flat top: its height varies, with no step between neighbours above 10 % of the range.
    top = ~down & ~side
    z = v[mesh.faces[top]][..., 2]
    assert z.max() - z.min() > 0.02
    assert np.abs(np.diff(z, axis=1)).max() < 0.1 * (z.max() - z.min()) + 0.02


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: generated_shape("cone"), "unknown generated shape 'cone'; valid: "),
        (lambda: generated_shape("bowl", depth=2), r"unknown parameters \['depth'\] for generated shape 'bowl'"),
        (lambda: generated_shape("bowl", thickness=0.9), r"bowl: parameter thickness must be in"),
        (lambda: generated_shape("extrusion", points="many"), "extrusion: parameter points must be a number"),
        (lambda: generated_shape("multipart", seed=-1), "seed must be a non-negative integer"),
    ],
)
def test_bad_names_and_parameters_raise_one_line(call, message):
    with pytest.raises(ValueError, match=message) as info:
        call()
    assert "\n" not in str(info.value)


@pytest.mark.mitsuba
@pytest.mark.parametrize("seed", [0, 1])
def test_heightfield_slab_renders_finite_stokes(tmp_path, seed):
    """The slab's sharp edges once produced NaN Stokes vectors: it must render and make a valid sample."""
    pytest.importorskip("mitsuba")
    from blender_addon.core import assets, placement, render, scenegen
    from blender_addon.core.spec import ObjectSpec, SceneSpec
    from pbrdf.data import sample as psample
    from pbrdf.sensor.rig import Rig

    ply = tmp_path / "slab.ply"
    assets.write_ply(generated_shape("heightfield_slab", seed=seed), ply)
    rng = np.random.default_rng(seed)
    rig = Rig()
    to_world = placement.place(assets.load_mesh(str(ply)), rig, rng)
    material = scenegen.random_material(rng, metal_fraction=float(seed))  # a plastic, then a metal
    obj = ObjectSpec("slab", str(ply), tuple(map(tuple, to_world)), material.name)
    spec = SceneSpec(rig=rig, objects=(obj,), materials=(material,), seed=seed)
    result = render.render_stokes(spec, render.RenderSettings(resolution=48, spp=4))
    assert np.isfinite(result.stokes).all() and result.mask.sum() > 100
    sample, meta = render.synthesize_sample(spec, result, rng=np.random.default_rng(0))
    psample.validate_sample(sample, meta)
