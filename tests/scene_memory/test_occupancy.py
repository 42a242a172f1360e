"""The occupancy map against OctoMap's semantics: a wall seen head-on, clamping, max range,
bit-for-bit state counts against OctoMap itself (pyoctomap) on the same scan."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.scene_memory.occupancy import (
    STATE_FREE,
    STATE_OCCUPIED,
    STATE_UNKNOWN,
    OccupancyConfig,
    OccupancyMap,
)

W, H, F = 320, 240, 288.0  # a small camera: 58° × 45°, pixels 4.5 mm apart at 1.3 m
LO, HI = np.array([0.0, -1.0, 0.0]), np.array([2.4, 1.0, 2.0])


def camera_facing_x(x: float = 0.2, z: float = 1.0) -> np.ndarray:
    """T_world_camera at (x, 0, z), optical axis +x, image x to −y, image y down."""
    T = np.eye(4)
    T[:3, :3] = np.column_stack([[0.0, -1, 0], [0.0, 0, -1], [1.0, 0, 0]])
    T[:3, 3] = [x, 0.0, z]
    return T


def wall_depth(distance: float) -> np.ndarray:
    """A wall perpendicular to the optical axis fills the image: constant depth."""
    return np.full((H, W), distance, np.float32)


def integrate(m: OccupancyMap, depth: np.ndarray, T: np.ndarray, **kw) -> int:
    return m.integrate_depth(depth, F, F, (W - 1) / 2, (H - 1) / 2, T, **kw)


def moving_scans(seed: int, far_rows: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Eight noisy depth images of six boxes 0.6-1.5 m before a wall at 1.79 m (the top
    ``far_rows`` rows past max range), from a camera moving 1 cm forward and 5 mm up a scan."""
    rng = np.random.default_rng(seed)
    base = np.full((H, W), 1.79, np.float32)
    for _ in range(6):
        r, c = rng.integers(0, H - 40), rng.integers(0, W - 40)
        base[r : r + rng.integers(20, 80), c : c + rng.integers(20, 100)] = rng.uniform(0.6, 1.5)
    base[:far_rows] = 3.6
    return [(base + rng.normal(0, 0.004, base.shape).astype(np.float32),
             camera_facing_x(0.2 + 0.01 * i, 1.0 + 0.005 * i)) for i in range(8)]  # fmt: skip


def state(m: OccupancyMap, point) -> int:
    p = m.probability(np.array(point, float))
    if p is None:
        return STATE_UNKNOWN
    return STATE_OCCUPIED if p > 0.5 else STATE_FREE


@pytest.mark.parametrize("voxel", [0.02, 0.01])
def test_a_wall_frees_the_space_before_it_and_hides_the_space_behind(voxel):
    m = OccupancyMap(LO, HI, OccupancyConfig(voxel=voxel))
    integrate(m, wall_depth(1.313), camera_facing_x())  # the wall at x = 1.513
    for x in (0.3, 0.8, 1.2, 1.45):  # between the camera and the wall, on the axis and off it
        assert state(m, (x, 0.0, 1.0)) == STATE_FREE
        assert state(m, (x, 0.2 * (x - 0.2), 1.0 - 0.15 * (x - 0.2))) == STATE_FREE
    for y, z in [(0.0, 1.0), (0.4, 1.2), (-0.5, 0.6)]:  # on the wall, inside the view
        assert state(m, (1.515, y, z)) == STATE_OCCUPIED
    for x in (1.56, 1.8, 2.3):  # behind it
        assert state(m, (x, 0.0, 1.0)) == STATE_UNKNOWN
    assert state(m, (1.0, 0.9, 1.0)) == STATE_UNKNOWN  # beside the view
    # the occupied voxels are the wall's slab and nothing else
    origin, states = m.states()
    occupied = np.argwhere(states == STATE_OCCUPIED) * voxel + origin + voxel / 2
    assert np.all(np.abs(occupied[:, 0] - 1.51) <= voxel)
    # its area: the view's footprint at 1.313 m, (1.313 · W / F) × (1.313 · H / F)
    area = len(occupied) * voxel**2
    assert area == pytest.approx(1.313**2 * W * H / F**2, rel=0.08)
    unknown, free, occ = m.counts()
    assert occ == len(occupied) and unknown + free + occ == states.size


def test_repeated_hits_and_misses_saturate_at_the_clamping_bounds():
    c = OccupancyConfig(voxel=0.02)
    m = OccupancyMap(LO, HI, c)
    wall, free = (1.515, 0.0, 1.0), (0.9, 0.0, 1.0)
    history = []
    for _ in range(12):
        integrate(m, wall_depth(1.313), camera_facing_x())
        history.append((m.probability(np.array(wall)), m.probability(np.array(free))))
    # one hit: p_hit; one miss: p_miss (Eq. of OctoMap: l = logit(p) per update)
    assert history[0][0] == pytest.approx(c.p_hit, abs=1e-3)
    assert history[0][1] == pytest.approx(c.p_miss, abs=1e-3)
    # 0.7 → 0.845 → 0.927 → 0.967 → 0.97 (clamped): rises, then stays at clamp_max
    hits = [h for h, _ in history]
    assert hits[1] > hits[0] and hits[2] > hits[1]
    assert all(h == pytest.approx(c.clamp_max, abs=1e-3) for h in hits[4:])
    misses = [f for _, f in history]
    assert all(f == pytest.approx(c.clamp_min, abs=1e-3) for f in misses[5:])
    assert min(misses) >= c.clamp_min - 1e-3 and max(hits) <= c.clamp_max + 1e-3
    # and a hit after saturation at clamp_min pulls it straight back by one step of l_hit
    back = math.log(c.clamp_min / (1 - c.clamp_min)) + math.log(c.p_hit / (1 - c.p_hit))
    integrate(m, wall_depth(0.71), camera_facing_x())  # the wall now at x = 0.91
    assert m.probability(np.array([0.915, 0.0, 1.0])) == pytest.approx(
        1 / (1 + math.exp(-back)), abs=1e-3
    )


def test_a_return_past_max_range_marks_nothing_occupied():
    m = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.02, max_range=1.0))
    integrate(m, wall_depth(1.313), camera_facing_x())
    _, free, occupied = m.counts()
    assert occupied == 0 and free > 0
    assert state(m, (0.9, 0.0, 1.0)) == STATE_FREE  # cleared up to the range ...
    assert state(m, (1.25, 0.0, 1.0)) == STATE_UNKNOWN  # ... and not beyond it
    assert state(m, (1.515, 0.0, 1.0)) == STATE_UNKNOWN


def test_returns_past_max_range_cast_one_ray_per_voxel_of_their_cut():
    """A wall 6 m away with a 1 m range: ~6 pixels' rays through each 2 cm voxel at the cut,
    each pixel its own voxel at the wall. One ray per cut voxel clears nearly what every ray
    does: this is the worst case, every return beyond range in one frame (3 % fewer free
    voxels, all beside the cut; 0.2 % over benchmarks/occupancy.py's kitchen pan)."""
    depth, T = wall_depth(6.0), camera_facing_x()
    merged = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.02, max_range=1.0))
    every = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.02, max_range=1.0, discretize=False))
    integrate(merged, depth, T)
    integrate(every, depth, T)
    assert every.rays == W * H
    assert merged.rays < 0.1 * W * H  # 2.9 k cut voxels
    _, f0, o0 = every.counts()
    _, f1, o1 = merged.counts()
    assert o0 == o1 == 0 and f0 > 5_000
    assert 0.965 * f0 <= f1 <= f0


def test_invalid_depths_are_skipped_and_rays_leaving_the_map_clip():
    m = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.02))
    depth = wall_depth(1.313)
    depth[:, : W // 2] = np.nan  # the left half of the image gives no return
    depth[0, :] = 0.0
    n = integrate(m, depth, camera_facing_x())
    assert n > 0
    assert state(m, (1.515, 0.3, 1.0)) == STATE_UNKNOWN  # image left = world +y
    assert state(m, (1.515, -0.3, 1.0)) == STATE_OCCUPIED
    # a camera outside the map looking in: only the part of each ray inside is updated
    outside = OccupancyMap(np.array([1.0, -1.0, 0.0]), HI, OccupancyConfig(voxel=0.02))
    integrate(outside, wall_depth(1.313), camera_facing_x())
    assert state(outside, (1.2, 0.0, 1.0)) == STATE_FREE
    assert state(outside, (1.515, 0.0, 1.0)) == STATE_OCCUPIED


def test_snapshots_keep_the_map_and_not_the_scratch():
    import pickle

    m = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.02))
    integrate(m, wall_depth(1.313), camera_facing_x())
    blob = pickle.dumps(m)
    # neither the scratch bit sets nor the unknown voxels are in it
    assert len(blob) < 0.2 * m.L.nbytes
    back = pickle.loads(blob)
    assert back.counts() == m.counts()
    # the known voxels' bit set is rebuilt from the values: the gain a frame would realise is
    # the same on both maps (a wall farther off, seen from beside the first view)
    T, farther = camera_facing_x(0.25, 1.1), wall_depth(1.8)
    box = (np.array([0.4, -0.6, 0.5]), np.array([2.2, 0.6, 1.5]))
    gain = m.unknown_on_rays(farther, (F, F, (W - 1) / 2, (H - 1) / 2), T, box, every=7)
    assert gain > 1000
    assert back.unknown_on_rays(farther, (F, F, (W - 1) / 2, (H - 1) / 2), T, box, every=7) == gain
    assert np.array_equal(back._known_bits, m._known_bits)
    integrate(back, wall_depth(1.313), camera_facing_x())
    integrate(m, wall_depth(1.313), camera_facing_x())
    assert np.array_equal(back.L, m.L)


def test_same_states_as_octomap_on_a_cluttered_scan():
    """A scan of boxes at several depths, with holes and far returns: our unknown / free /
    occupied counts equal OctoMap's (pyoctomap, insertPointCloud with discretize) within 1 %."""
    pyoctomap = pytest.importorskip("pyoctomap")
    from benchmarks.occupancy import octomap_states

    rng = np.random.default_rng(3)
    depth = np.full((H, W), 1.79, np.float32)
    for _ in range(6):
        r, c = rng.integers(0, H - 40), rng.integers(0, W - 40)
        depth[r : r + rng.integers(20, 80), c : c + rng.integers(20, 100)] = rng.uniform(0.5, 1.5)
    depth[rng.random((H, W)) < 0.05] = 0.0  # dropouts
    depth[:20, :] = 3.5  # beyond max range
    T = camera_facing_x()
    voxel = 0.02
    m = OccupancyMap(LO, HI, OccupancyConfig(voxel=voxel, max_range=3.0))
    integrate(m, depth, T)
    v, u = np.nonzero(depth > 0)
    d = depth[v, u].astype(np.float64)
    cam = np.column_stack([(u - (W - 1) / 2) / F * d, (v - (H - 1) / 2) / F * d, d])
    points = cam @ T[:3, :3].T + T[:3, 3]
    tree = pyoctomap.OcTree(voxel)
    tree.insertPointCloud(points, T[:3, 3].copy(), 3.0, False, True)
    theirs = octomap_states(tree, LO, m.shape, voxel)
    _, ours = m.states()
    for s in (STATE_UNKNOWN, STATE_FREE, STATE_OCCUPIED):
        a, b = int((ours == s).sum()), int((theirs == s).sum())
        assert abs(a - b) <= 0.01 * b, (s, a, b)
    # and voxel by voxel they agree almost everywhere
    assert (ours != theirs).mean() < 0.001


def test_the_gain_a_frame_realises_is_counted_both_ways():
    """``volume``: roi voxels a frame made known (the memory's count before and after it);
    ``rays``: Eq. 4.6 on the frame's own rays up to their returns, checked against every
    crossing of each ray with the voxel planes; a second look at the wall realises nothing."""
    from schemas import CameraIntrinsics, RgbdFrame
    from services.scene_memory.memory import MemoryConfig, SceneMemory

    K = CameraIntrinsics(width=W, height=H, fx=F, fy=F, cx=(W - 1) / 2, cy=(H - 1) / 2)

    def make_frame(depth, T):
        return RgbdFrame(seq=0, stamp=0.0, camera="head_rgbd", intrinsics=K, rgb=None,
                         depth=depth, T_world_camera=T, depth_min=0.35, depth_max=3.0)  # fmt: skip

    roi = ((1.0, -0.3, 0.7), (1.6, 0.3, 1.3))
    memory = SceneMemory(MemoryConfig(bounds_min=tuple(LO), bounds_max=tuple(HI), roi=roi))
    T, depth = camera_facing_x(), wall_depth(1.313)
    T[:3, 3] = [0.2037, 0.0041, 1.0013]  # off the voxel grid: no ray runs along an edge
    m = memory.occupancy
    expected = 0
    v, u = np.divmod(np.arange(0, W * H, 30), W)
    for uu, vv in zip(u, v, strict=True):
        d = np.array([(uu - (W - 1) / 2) / F, (vv - (H - 1) / 2) / F, 1.0]) * depth[0, 0]
        end = T[:3, :3] @ d + T[:3, 3]
        # every crossing of a voxel boundary plane: each piece between two lies in one voxel
        o, step = T[:3, 3] - m.lo, end - T[:3, 3]
        ts = [0.0, 1.0]
        for a in range(3):
            k = np.arange(m.shape[a] + 1) * m.voxel
            t = (k - o[a]) / step[a]
            ts += [x for x in t if 0 < x < 1]
        ts = np.unique(ts)
        mids = o + (ts[:-1] + ts[1:])[:, None] / 2 * step
        keys = {tuple(k) for k in np.floor(mids / m.voxel).astype(int)}
        lo_k, hi_k = m._index_box(*roi)[:3], m._index_box(*roi)[3:]
        expected += sum(all(lo_k[a] <= k[a] < hi_k[a] for a in range(3)) for k in keys)
    before = m.counts(*roi)[0]
    memory.integrate(make_frame(depth, T))
    assert memory.realised_gain["volume"] == before - m.counts(*roi)[0] > 10_000
    assert memory.realised_gain["rays"] == pytest.approx(
        30 * expected, rel=1e-4
    )  # a ray may graze an edge
    memory.integrate(make_frame(depth, T))
    assert memory.realised_gain == {"volume": 0.0, "rays": 0.0}


def test_a_scan_counts_the_voxels_it_makes_known_in_a_box_as_it_updates_them():
    """``made_known``: the unknown voxels of a box that a scan made known, counted while the
    scan updates them, is the box's unknown count before minus after, scan after scan, for
    boxes that cut the rays' paths anywhere (and the whole map without one)."""
    rng = np.random.default_rng(7)
    m = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.02))
    boxes = [((0.5, -0.4, 0.3), (1.3, 0.5, 1.4)), ((1.1, -1.0, 0.0), (2.4, 0.0, 0.9)), None]
    for scan in range(6):
        origin = np.array([0.2 + 0.1 * scan, rng.uniform(-0.3, 0.3), rng.uniform(0.8, 1.2)])
        points = rng.uniform(LO + 0.05, HI - 0.05, (3000, 3))
        box = boxes[scan % 3]
        before = m.counts(*box)[0] if box else m.counts()[0]
        m.integrate(points, origin, box=box)
        after = m.counts(*box)[0] if box else m.counts()[0]
        assert m.made_known == before - after > 0
    m.integrate(points, origin, box=boxes[0])  # the same scan again: nothing new
    assert m.made_known == 0


def test_rays_cross_saturated_free_blocks_in_one_step_and_change_nothing():
    """Rays cross a block whose voxels are all free at the clamp (where a miss is a no-op) in
    one step. With every ray walked whole (no early stop), eight scans from a moving camera give
    exactly the map they give voxel by voxel (``skip_saturated=False``), which updates the
    saturated voxels too (to the clamp they are at: more voxels updated, the same values and
    the same saturated blocks); an object then put into that saturated free space is updated
    by every hit (occupied after the third)."""
    scans = moving_scans(5)
    skipping = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.02, early_stop=False))
    walking = OccupancyMap(
        LO, HI, OccupancyConfig(voxel=0.02, early_stop=False, skip_saturated=False)
    )
    updated = [(integrate(skipping, depth, T), integrate(walking, depth, T)) for depth, T in scans]
    assert skipping._saturated.sum() > 100  # the free space before the boxes saturated
    assert np.array_equal(skipping.L, walking.L)
    assert np.array_equal(skipping._saturated, walking._saturated)
    assert updated[0][0] == updated[0][1]  # nothing saturated yet: the same walk
    assert all(w >= s for s, w in updated)
    assert updated[-1][1] > updated[-1][0] + 1000  # the saturated voxels' updates
    # a box appears 0.43 m before the camera, in free space that saturated
    spot = np.array([0.71, 0.0, 1.0])
    i = np.floor((spot - LO) / 0.02).astype(int)
    by, bz = (np.array(skipping.shape[1:]) + 7) // 8
    assert skipping._saturated[((i[0] >> 3) * by + (i[1] >> 3)) * bz + (i[2] >> 3)]
    depth = scans[-1][0].copy()
    depth[110:170, 130:190] = 0.43
    for k in range(3):  # from the free clamp, the third hit makes it occupied
        for m in (skipping, walking):
            integrate(m, depth, scans[-1][1])
        assert state(skipping, spot) == (STATE_OCCUPIED if k == 2 else STATE_FREE)
    assert np.array_equal(skipping.L, walking.L)
    # a snapshot rebuilds the saturated blocks from the values
    restored = OccupancyMap.__new__(OccupancyMap)
    restored.__setstate__(skipping.__getstate__())
    assert np.array_equal(restored._saturated, skipping._saturated)


def test_without_the_early_stop_every_ray_is_walked_whole():
    """``early_stop=False`` walks every ray to the sensor. A ray through space cleared before
    it steps through PATIENCE_REST voxels of it with the early stop, through all of them
    without. Where no ray runs through space that rays before it cleared (40 rays 10° apart),
    the map and the voxels updated are those of the early-stopping walk; on a full frame of
    boxes before a wall, whose finer rays run beside coarser ones, it updates more voxels,
    every one the early stop updated among them, each to the same value, from the same rays."""
    from services.scene_memory import occupancy

    # one ray, 59 voxels long, through a 64³ map all of which earlier rays cleared
    n, voxel = 64, 0.01
    bits = ((n + 7) // 8) ** 3 * 64
    cleared, saturated, dirty = np.full(bits, 255, np.uint8), np.zeros(bits // 64, np.uint8), \
        np.zeros(bits // 64, np.uint8)  # fmt: skip
    origin, end = np.array([0.025, 0.325, 0.325]), np.array([0.615, 0.325, 0.325])
    steps = []
    for patience in (occupancy.PATIENCE_REST, 0):
        visited = np.zeros(bits, np.uint8)
        occupancy._walk(visited, cleared, saturated, dirty, n, n, n, np.zeros(3), voxel, origin,
                        end, 3.0, patience)  # fmt: skip
        steps.append(int(np.unpackbits(visited).sum()))
    assert steps == [occupancy.PATIENCE_REST, 59]  # the end's own voxel is the hit's

    T = camera_facing_x()
    angles = np.radians(np.arange(-35, 40, 10))
    a, b = (g.ravel() for g in np.meshgrid(angles, np.radians(np.arange(-20, 25, 10))))
    directions = np.column_stack([np.cos(a) * np.cos(b), np.sin(a) * np.cos(b), np.sin(b)])
    points = T[:3, 3] + 1.2 * directions
    sparse = [OccupancyMap(LO, HI, OccupancyConfig(voxel=0.01, early_stop=e)) for e in (1, 0)]
    counts = [m.integrate(points, T[:3, 3]) for m in sparse]
    assert len(points) == 40 and counts[0] == counts[1] > 40 * 100
    assert np.array_equal(sparse[0].L, sparse[1].L)

    depth, T = moving_scans(5)[0]
    stopping, whole = (OccupancyMap(LO, HI, OccupancyConfig(voxel=0.01, early_stop=e))
                       for e in (True, False))  # fmt: skip
    n_stop, n_whole = integrate(stopping, depth, T), integrate(whole, depth, T)
    assert stopping.rays == whole.rays > 40_000
    assert n_whole > n_stop + 100  # voxels of finer rays beside the coarser ones they joined
    L_stop, L_whole = stopping.L, whole.L
    known = L_stop != -32768
    assert np.array_equal(L_whole[known], L_stop[known])
    assert int((L_whole != -32768).sum()) == n_whole and int(known.sum()) == n_stop


def test_one_thread_by_config_gives_the_map_of_the_whole_pool(monkeypatch):
    """``threads=1`` integrates on one thread of numba's pool (the pool set to one for the
    call, then restored; one visited set) and gives, voxel by voxel, the map the whole pool
    gives."""
    numba = pytest.importorskip("numba")
    from services.scene_memory import occupancy

    if numba.get_num_threads() < 2:
        pytest.skip("one thread only")
    pool = numba.get_num_threads()
    asked = []
    real = numba.set_num_threads

    def spy(n: int) -> None:
        asked.append(n)
        real(n)

    monkeypatch.setattr(numba, "set_num_threads", spy)
    scans = moving_scans(11, far_rows=30)
    one = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.01, threads=1))
    every = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.01))
    for depth, T in scans:
        integrate(one, depth, T)
        assert asked[-2:] == [1, pool] and numba.get_num_threads() == pool
        asked.clear()
        integrate(every, depth, T)
        assert asked == [pool]  # the whole pool: never lowered
    assert len(one._visited) == 1 and len(every._visited) == min(pool, occupancy.WALK_THREADS)
    assert one.counts()[1] > 100_000
    assert np.array_equal(one.L, every.L)
    assert np.array_equal(one._saturated, every._saturated)


def test_the_map_is_the_same_whichever_threads_walk_the_rays(monkeypatch):
    """Each walking thread marks its visits in a bit set of its own; the rounds' stops and the
    updates read their union. Eight scans from a moving camera give, voxel by voxel, the map
    one thread gives, with two threads and with more threads than the map has sets (capped)."""
    numba = pytest.importorskip("numba")
    from services.scene_memory import occupancy

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one thread only")
    scans = moving_scans(11, far_rows=30)
    maps = {}
    before = numba.get_num_threads()
    try:
        for threads, cap in ((1, 8), (2, 8), (2, 1)):
            numba.set_num_threads(threads)
            monkeypatch.setattr(occupancy, "WALK_THREADS", cap)
            m = maps[threads, cap] = OccupancyMap(LO, HI, OccupancyConfig(voxel=0.01))
            for depth, T in scans:
                integrate(m, depth, T)
                assert m.rays > 2 * occupancy.SUBPASSES * occupancy.SMALL_PASS  # rounds, threads
            assert not m._visited.any() and len(m._visited) == min(threads, cap)
    finally:
        numba.set_num_threads(before)
    one = maps[1, 8]
    assert one.counts()[1] > 100_000
    for m in maps.values():
        assert np.array_equal(m.L, one.L)
        assert np.array_equal(m._saturated, one._saturated)
