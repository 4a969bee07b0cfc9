"""Point ops against brute-force implementations (CPU, small sizes)."""

from __future__ import annotations

import pytest
import torch

from floaff_zoo.nn import _fps_ext, cfar, ops


def naive_fps(xyz: torch.Tensor, mask: torch.Tensor, npoint: int) -> torch.Tensor:
    """Python loop over one cloud at a time, start at the first valid point."""
    out = []
    for b in range(xyz.shape[0]):
        valid = torch.nonzero(mask[b]).flatten().tolist()
        dist = {i: float("inf") for i in valid}
        cur = valid[0]
        picks = []
        for _ in range(npoint):
            picks.append(cur)
            c = xyz[b, cur]
            for i in valid:
                d = float(((xyz[b, i] - c) ** 2).sum())
                dist[i] = min(dist[i], d)
            best = max(dist.values())
            cur = min(i for i in valid if dist[i] == best)
        out.append(picks)
    return torch.tensor(out)


def brute_ball(radius, k, xyz, new_xyz, mask):
    b, s = new_xyz.shape[:2]
    out = torch.empty(b, s, k, dtype=torch.long)
    for i in range(b):
        for j in range(s):
            d = ((xyz[i] - new_xyz[i, j]) ** 2).sum(-1)
            inside = [t for t in range(xyz.shape[1]) if mask[i, t] and d[t] <= radius**2]
            inside = inside[:k]
            out[i, j] = torch.tensor(inside + [inside[0]] * (k - len(inside)))
    return out


@pytest.fixture
def cloud():
    g = torch.Generator().manual_seed(0)
    xyz = torch.rand(3, 96, 3, generator=g)
    mask = torch.ones(3, 96, dtype=torch.bool)
    mask[1, 60:] = False
    mask[2, ::3] = False  # index 0 invalid: start moves to the first valid point
    return xyz, mask


def test_fps_torch_matches_naive_loop(cloud):
    xyz, mask = cloud
    got = ops.farthest_point_sample_torch(xyz, mask, 20)
    assert torch.equal(got, naive_fps(xyz, mask, 20))
    assert mask.gather(1, got).all()
    assert got[0, 0] == 0 and got[2, 0] == 1


def test_fps_default_backend_matches_torch(cloud):
    xyz, mask = cloud
    assert torch.equal(ops.farthest_point_sample(xyz, mask, 24), ops.farthest_point_sample_torch(xyz, mask, 24))


def test_fps_cpp_kernel_when_available(monkeypatch):
    """The C++ kernel (if a compiler exists) is exact on a larger batch; skipped otherwise."""
    monkeypatch.setenv("FLOAFF_ZOO_FPS_BACKEND", "auto")
    kernel = _fps_ext.load_kernel()
    if kernel is None:
        pytest.skip(f"C++ FPS kernel unavailable: {_fps_ext._state['error']}")
    xyz = torch.rand(4, 2048, 3, generator=torch.Generator().manual_seed(1))
    mask = torch.rand(4, 2048, generator=torch.Generator().manual_seed(2)) > 0.2
    got = kernel.fps_forward(xyz, mask, 256)
    assert torch.equal(got, ops.farthest_point_sample_torch(xyz, mask, 256))


def test_fps_force_fallback_env(monkeypatch):
    monkeypatch.setenv("FLOAFF_ZOO_FPS_BACKEND", "torch")
    assert ops.fps_backend() == "torch"
    monkeypatch.setenv("FLOAFF_ZOO_FPS_BACKEND", "bogus")
    with pytest.raises(ValueError, match="FLOAFF_ZOO_FPS_BACKEND"):
        ops.fps_backend()


def test_fps_fewer_valid_points_repeats_valid(cloud):
    xyz, _ = cloud
    mask = torch.zeros(1, 96, dtype=torch.bool)
    mask[0, [5, 17, 40]] = True
    idx = ops.farthest_point_sample(xyz[:1], mask, 8)
    assert set(idx[0, :3].tolist()) == {5, 17, 40}
    assert mask.gather(1, idx).all()  # the tail repeats valid points, never padding


def test_fps_no_valid_point_raises(cloud):
    xyz, mask = cloud
    mask = mask.clone()
    mask[1] = False
    with pytest.raises(ValueError, match=r"cloud\(s\) \[1\]"):
        ops.farthest_point_sample(xyz, mask, 4)


def test_ball_query_matches_brute_force_and_sort_version(cloud):
    xyz, mask = cloud
    centres = ops.index_points(xyz, ops.farthest_point_sample(xyz, mask, 12))
    got = ops.ball_query(0.3, 8, xyz, centres, mask)
    assert torch.equal(got, brute_ball(0.3, 8, xyz, centres, mask))
    assert mask.gather(1, got.flatten(1)).all()
    # classic sort-based version (all points valid)
    full = torch.ones_like(mask)
    n = xyz.shape[1]
    key = torch.arange(n).repeat(3, 12, 1)
    key[ops.square_distance(centres, xyz) > 0.3**2] = n
    key = key.sort(dim=-1)[0][..., :8]
    key = torch.where(key == n, key[..., :1], key)
    assert torch.equal(ops.ball_query(0.3, 8, xyz, centres, full), key)


def test_ball_query_chunked_equals_unchunked(cloud, monkeypatch):
    xyz, mask = cloud
    centres = xyz[:, :30]
    ref = ops.ball_query(0.25, 6, xyz, centres, mask)
    monkeypatch.setattr(ops, "_CHUNK_ELEMS", 3 * 96 * 7)
    assert torch.equal(ops.ball_query(0.25, 6, xyz, centres, mask), ref)


def test_ball_query_empty_ball_uses_nearest_valid():
    xyz = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0], [5.0, 0, 0]]])
    mask = torch.tensor([[False, True, True]])
    idx = ops.ball_query(0.1, 4, xyz, torch.tensor([[[0.0, 0, 0]]]), mask)
    assert idx.tolist() == [[[1, 1, 1, 1]]]


def test_knn_matches_brute_force(cloud):
    xyz, mask = cloud
    q = torch.rand(3, 10, 3)
    d, idx = ops.knn(5, xyz, q, mask)
    for b in range(3):
        for j in range(10):
            dist = ((xyz[b] - q[b, j]) ** 2).sum(-1).masked_fill(~mask[b], float("inf"))
            ref = dist.argsort()[:5]
            assert idx[b, j].tolist() == ref.tolist()
            assert torch.allclose(d[b, j], dist[ref], atol=1e-5)


def test_three_interpolate_matches_brute_force(cloud):
    xyz, mask = cloud
    # seeded: unseeded queries failed once in a full run, most likely a near-tie for the 3rd neighbour
    # (float32 matmul distances vs the exact ones below pick different points)
    g = torch.Generator().manual_seed(3)
    feat = torch.randn(3, 96, 4, generator=g)
    q = torch.rand(3, 7, 3, generator=g)
    got = ops.three_interpolate(q, xyz, feat, mask)
    for b in range(3):
        for j in range(7):
            d = ((xyz[b] - q[b, j]) ** 2).sum(-1).masked_fill(~mask[b], float("inf"))
            nn3 = d.argsort()[:3]
            w = 1.0 / (d[nn3] + 1e-8)
            ref = (feat[b, nn3] * (w / w.sum())[:, None]).sum(0)
            assert torch.allclose(got[b, j], ref, atol=1e-5)


def test_three_interpolate_few_known_points():
    known = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0]]])
    feat = torch.tensor([[[1.0], [3.0]]])
    out = ops.three_interpolate(torch.tensor([[[0.5, 0, 0]]]), known, feat)
    assert torch.allclose(out, torch.tensor([[[2.0]]]))
    single = ops.three_interpolate(torch.rand(1, 4, 3), known[:, :1], feat[:, :1])
    assert torch.equal(single, torch.ones(1, 4, 1))
    masked = ops.three_interpolate(torch.rand(1, 4, 3), known, feat, torch.tensor([[False, True]]))
    assert torch.allclose(masked, torch.full((1, 4, 1), 3.0))


@pytest.mark.parametrize("m", [1, 2, 5])
def test_three_interpolate_with_no_valid_known_point_gives_zeros(m):
    """A sample whose known points are all padding gave NaN (0 / 0 weights; a lone masked point was broadcast), which
    a decoder carried into the loss; the other samples keep their exact values."""
    gen = torch.Generator().manual_seed(0)
    known, feat = torch.rand(2, m, 3, generator=gen), torch.randn(2, m, 4, generator=gen)
    unknown = torch.rand(2, 6, 3, generator=gen)
    mask = torch.ones(2, m, dtype=torch.bool)
    mask[1] = False
    out = ops.three_interpolate(unknown, known, feat, mask)
    assert torch.equal(out[1], torch.zeros(6, 4))
    assert torch.equal(out[:1], ops.three_interpolate(unknown[:1], known[:1], feat[:1], mask[:1]))
    # the valid sample against a brute-force reference: its (up to) 3 nearest, weights 1 / (d^2 + 1e-8) normalised
    d2 = ((unknown[0, :, None].double() - known[0, None].double()) ** 2).sum(-1)  # [6, m]
    near, idx = d2.topk(min(m, 3), dim=1, largest=False)
    w = 1.0 / (near + 1e-8)
    ref = ((w / w.sum(1, keepdim=True))[..., None] * feat[0].double()[idx]).sum(1)  # [6, 4]
    assert torch.allclose(out[0].double(), ref, atol=1e-5)


@pytest.mark.parametrize("path", ["fast", "portable"])
def test_three_interpolate_of_near_coincident_points_stays_within_its_features(monkeypatch, path):
    """The search's expanded distance went below 0 for a query on a known point with two more 0.3-0.6 mm away:
    1 / (d + 1e-8) gave weights of both signs, and features 1, 2 and 3 interpolated to -776 on one path, 1.10 on
    the other. The weights now come from the picks' coordinate differences, as the official kernel's."""
    monkeypatch.setenv(ops.CPU_PATHS_ENV, path)
    torch.manual_seed(0)
    worst_low, worst_high = 1.0, 3.0
    for scale, eps in ((0.5, 1e-4), (1.0, 3e-4), (2.0, 1e-3), (4.0, 1e-4)):
        u = torch.rand(1, 2000, 3) * scale
        known = torch.cat([u + torch.randn_like(u) * eps, u + torch.randn_like(u) * eps, u], 1)
        feat = torch.cat([torch.full((1, 2000, 1), v) for v in (1.0, 2.0, 3.0)], 1)
        out = ops.three_interpolate(u, known, feat)
        worst_low, worst_high = min(worst_low, float(out.min())), max(worst_high, float(out.max()))
    assert worst_low >= 1.0 - 1e-5 and worst_high <= 3.0 + 1e-5  # a convex combination of the features


def test_index_points_gradients_flow():
    feat = torch.randn(2, 10, 3, requires_grad=True)
    idx = torch.randint(0, 10, (2, 4, 5))
    out = ops.index_points(feat, idx)
    assert out.shape == (2, 4, 5, 3)
    assert torch.equal(out.detach(), feat.detach()[torch.arange(2)[:, None, None], idx])
    out.sum().backward()
    assert feat.grad is not None and feat.grad.sum() == 2 * 4 * 5 * 3


def test_neighbour_search_runs_fp32_under_bf16_autocast(cloud):
    xyz, mask = cloud
    with torch.autocast("cpu", dtype=torch.bfloat16):
        d = ops.square_distance(xyz, xyz)
    assert d.dtype == torch.float32


def test_bad_shapes_and_nan():
    with pytest.raises(ValueError, match="xyz must be"):
        ops.farthest_point_sample(torch.rand(2, 5, 2), None, 2)
    with pytest.raises(ValueError, match="scene_xyz contains 1 NaN"):
        x = torch.rand(2, 5, 3)
        x[0, 0, 0] = float("nan")
        ops.check_finite("scene_xyz", x)


def _neighbour_case(seed: int = 3):
    """A cloud big enough for several vector blocks and ragged tails: 2 x 1,003 points (some masked), 301 centres."""
    g = torch.Generator().manual_seed(seed)
    xyz = torch.rand(2, 1003, 3, generator=g) * torch.tensor([2.0, 1.5, 1.0]) - 0.5
    mask = torch.rand(2, 1003, generator=g) > 0.1
    centres = xyz[:, 1:302] + 0.01 * torch.randn(2, 301, 3, generator=g)
    return xyz, mask, centres


def test_ball_query_and_three_nn_kernels_match_the_torch_path(monkeypatch):
    """The C++ kernels compute each distance row as the torch path's GEMM rounds it: same distances bit for bit,
    so the same neighbours (several scales at once, masked points, empty balls)."""
    if ops.point_kernel(torch.device("cpu")) is None:
        pytest.skip("C++ point-op kernels unavailable (no compiler): only the torch path exists")
    xyz, mask, centres = _neighbour_case()
    far = torch.tensor([[[9.0, 9.0, 9.0]]]).expand(2, 1, 3)  # no point within any radius: nearest valid point
    centres = torch.cat([centres, far], dim=1)
    radii, ks = [0.05, 0.1, 0.2], [4, 16, 32]
    fast = ops.ball_query_multi(radii, ks, xyz, centres, mask)
    d_fast, i_fast = ops.three_nn(centres, xyz, mask)
    monkeypatch.setattr(ops, "point_kernel", lambda device: None)  # force the torch path
    ref = ops.ball_query_multi(radii, ks, xyz, centres, mask)
    d_ref, i_ref = ops.three_nn(centres, xyz, mask)
    for got, want in zip(fast, ref):
        assert torch.equal(got, want)
    assert torch.equal(d_fast, d_ref) and torch.equal(i_fast, i_ref)
    assert mask.gather(1, fast[2].flatten(1)).all()


def test_three_nn_breaks_ties_alike_on_every_path(monkeypatch):
    """On a regular floor grid distances tie exactly: the torch path (CUDA, portable) took other neighbours than the
    C++ kernel for ~9 % of the grid (topk orders ties arbitrarily), so interpolated features differed."""
    xs = torch.arange(-20, 21, dtype=torch.float32) * 0.05
    grid = torch.stack(torch.meshgrid(xs, xs, indexing="ij"), -1).reshape(1, -1, 2)
    grid = torch.cat([grid, torch.zeros(1, grid.shape[1], 1)], -1)  # [1, 1681, 3]
    centres = ops.index_points(grid, ops.farthest_point_sample(grid, None, 128))
    known_feat = torch.randn(1, 128, 4, generator=torch.Generator().manual_seed(0))
    fast = ops.three_nn(grid, centres)
    fast_feat = ops.three_interpolate(grid, centres, known_feat)
    monkeypatch.setattr(ops, "point_kernel", lambda device: None)  # the torch path
    slow = ops.three_nn(grid, centres)
    assert torch.equal(fast[1], slow[1]) and torch.equal(fast[0], slow[0])
    assert torch.equal(fast_feat, ops.three_interpolate(grid, centres, known_feat))
    # the lowest index wins among equal distances: an unknown point at the origin, six known points at distance 1
    ring = torch.tensor([[[1.0, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]])
    assert ops.three_nn(torch.zeros(1, 1, 3), ring)[1].tolist() == [[[0, 1, 2]]]


def test_weighted_gather3_kernel_equals_gather_then_sum(monkeypatch):
    """The fused C++ gather + weighted sum of 3-NN interpolation sums in torch's order (bit for bit), keeps
    gradients on the torch path, and names bad indices."""
    if ops.point_kernel(torch.device("cpu")) is None:
        pytest.skip("C++ point-op kernels unavailable (no compiler): only the torch path exists")
    g = torch.Generator().manual_seed(4)
    feat = torch.randn(2, 57, 37, generator=g)
    idx = torch.randint(0, 57, (2, 211, 3), generator=g)
    weight = torch.rand(2, 211, 3, generator=g)
    want = (ops.index_points(feat, idx) * weight[..., None]).sum(dim=2)
    assert torch.equal(ops.weighted_gather3(feat, idx, weight), want)
    want64 = (ops.index_points(feat.double(), idx) * weight.double()[..., None]).sum(dim=2)
    assert torch.equal(ops.weighted_gather3(feat.double(), idx, weight.double()), want64)
    leaf = feat.clone().requires_grad_()
    ops.weighted_gather3(leaf, idx, weight).sum().backward()  # the torch path: differentiable
    assert leaf.grad is not None and torch.isfinite(leaf.grad).all()
    kernel = ops.point_kernel(torch.device("cpu"))
    with pytest.raises(RuntimeError, match="out of range"):
        kernel.weighted_gather3(feat, torch.full_like(idx, 57), weight)


def test_kernels_give_the_same_result_on_every_instruction_set():
    """The AVX-512, AVX2 and baseline builds of the loops (those the CPU runs) agree bit for bit."""
    from floaff_zoo.nn import _fps_ext

    kernel = _fps_ext.load_kernel()
    if kernel is None:
        pytest.skip("C++ point-op kernels unavailable (no compiler): only the torch path exists")
    xyz, mask, centres = _neighbour_case(5)
    # a grid: exact ties of the farthest distance everywhere (the lowest index must win across vector lanes)
    g = torch.arange(11.0)
    grid = torch.stack(torch.meshgrid(g, g, torch.arange(3.0), indexing="ij"), -1).reshape(1, -1, 3) * 0.1
    grid_ref = ops.farthest_point_sample_torch(grid, None, 60)
    best = kernel.kernel_isa(-1)
    results = []
    try:
        for level in range(best + 1):
            assert kernel.kernel_isa(level) == level
            assert torch.equal(ops.farthest_point_sample(grid, None, 60), grid_ref)
            fps = ops.farthest_point_sample(xyz, mask, 97)
            balls = ops.ball_query_multi([0.1, 0.3], [8, 24], xyz, centres, mask)
            results.append((fps, *balls, *ops.three_nn(centres, xyz, mask)))
    finally:
        kernel.kernel_isa(best)
    for other in results[1:]:
        assert all(torch.equal(a, b) for a, b in zip(results[0], other))


def test_cfar_tolerant_selections_kernel_matches_torch(monkeypatch):
    """CFAR's tie-tolerant FPS and 3-NN picks are the same from the C++ kernel and the torch loop."""
    from floaff_zoo.nn import cfar

    if ops.point_kernel(torch.device("cpu")) is None:
        pytest.skip("C++ point-op kernels unavailable (no compiler): only the torch path exists")
    g = torch.Generator().manual_seed(1)
    grid = torch.stack(torch.meshgrid(torch.arange(12.0), torch.arange(10.0), indexing="ij"), -1).reshape(-1, 2) * 0.05
    xyz = torch.cat([grid, torch.zeros(len(grid), 1)], -1)[None].repeat(2, 1, 1)  # ties everywhere
    xyz[1] += torch.rand(xyz.shape[1:], generator=g) * 1e-3
    mask = torch.ones(2, xyz.shape[1], dtype=torch.bool)
    mask[1, :7] = False
    known = xyz[:, ::5].contiguous()
    feat = torch.randn(2, known.shape[1], 4, generator=g)
    fast = cfar.tolerant_fps(xyz, mask, 40)
    fast_i = cfar.stable_three_interpolate(xyz, known, feat)
    monkeypatch.setattr(cfar, "point_kernel", lambda device: None)
    assert torch.equal(cfar.tolerant_fps(xyz, mask, 40), fast)
    assert (fast[1] >= 7).all()
    assert torch.allclose(cfar.stable_three_interpolate(xyz, known, feat), fast_i, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_extreme_over_dim_kernel_matches_torch_max_and_min(monkeypatch, dtype):
    """Max (min on flagged channels) with the first index among ties and NaN winning, as torch.max/min."""
    if ops.point_kernel(torch.device("cpu")) is None:
        pytest.skip("C++ point-op kernels unavailable (no compiler): only the torch path exists")
    g = torch.Generator().manual_seed(0)
    z = torch.randn(3, 5, 7, 6, generator=g, dtype=dtype)
    z[:, :, 4:] = z[:, :, :1]  # padded groups: exact ties with the first row
    z[1, 2, 3, 0] = float("nan")
    z[2, 0, 1:3, 4] = float("nan")  # two NaNs: the first one's index
    take_min = torch.tensor([False, True, False, True, False, False])
    got = ops.extreme_over_dim(z, 2, take_min)
    monkeypatch.setattr(ops, "point_kernel", lambda device: None)  # force the torch path
    ref = ops.extreme_over_dim(z, 2, take_min)
    assert torch.equal(got[1], ref[1])
    assert torch.allclose(got[0], ref[0], equal_nan=True)
    assert torch.equal(ref[1][..., 0], z.max(dim=2).indices[..., 0])
    assert torch.equal(ref[1][..., 1], z.min(dim=2).indices[..., 1])
    assert ref[1][2, 0, 4] == 1 and ref[1][1, 2, 0] == 3  # the first NaN
    with pytest.raises(ValueError, match="channel"):
        ops.extreme_over_dim(z, -1, take_min)


def test_build_folder_is_per_torch_install_under_the_extensions_dir(tmp_path, monkeypatch):
    """One folder per torch install (build.ninja holds its include paths) under TORCH_EXTENSIONS_DIR."""
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    folder = _fps_ext.build_directory()
    assert folder.parent == tmp_path / "floaff_zoo"
    assert folder.name.startswith(_fps_ext._NAME + "_") and folder.name.isidentifier()
    assert folder == _fps_ext.build_directory()


def test_build_guard_clears_the_baton_of_a_killed_compile(tmp_path):
    """A compile killed inside the guard leaves torch's plain 'lock' file; the next build removes it, not waits."""
    import subprocess
    import sys
    import textwrap

    folder = tmp_path / "ext"
    holder = textwrap.dedent(
        f"""
        import sys, time
        from pathlib import Path
        from floaff_zoo.nn._fps_ext import build_guard
        with build_guard(Path({str(folder)!r})):
            (Path({str(folder)!r}) / "lock").touch()  # torch's baton, as load_inline creates it
            print("holding", flush=True)
            time.sleep(120)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", holder], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "holding"
        fcntl = pytest.importorskip("fcntl")
        with open(tmp_path / "ext.flock", "a+") as handle:  # a live holder: the guard is really exclusive
            with pytest.raises(BlockingIOError):
                fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert (folder / "lock").exists()
    with pytest.warns(UserWarning, match="stale build lock"):
        with _fps_ext.build_guard(folder):
            assert not (folder / "lock").exists()


@pytest.mark.skipif(ops.point_kernel(torch.device("cpu")) is None, reason="no C++ point kernel")
def test_three_nn_distances_carry_no_gradient_on_either_path(monkeypatch):
    """VoteNet and H3DNet give three_nn learned vote positions: the C++ kernel's distances carry no gradient, and
    the torch path (CUDA, compile, FLOAFF_ZOO_CPU_PATHS=portable) gave them one, so the models trained differently."""
    torch.manual_seed(0)
    floor, votes, feat = torch.rand(1, 5, 3), torch.rand(1, 4, 3, requires_grad=True), torch.rand(1, 4, 2)
    out = {}
    for path in ("fast", "portable"):
        monkeypatch.setenv(ops.CPU_PATHS_ENV, path)
        out[path] = (ops.three_nn(floor, votes)[0], ops.three_interpolate(floor, votes, feat))
    assert [t.requires_grad for t in out["portable"]] == [t.requires_grad for t in out["fast"]] == [False, False]
    torch.testing.assert_close(out["portable"][0], out["fast"][0])


def test_stable_three_interpolate_in_float16_keeps_a_coincident_point_finite():
    """In float16 the weights' 1e-8 rounded to 0: a query on a known point got an infinite weight and a NaN value."""
    from floaff_zoo.nn.cfar import stable_three_interpolate

    known = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    feat = torch.tensor([[[1.0], [2.0], [3.0]]])
    query = torch.tensor([[[0.0, 0.0, 0.0], [0.5, 0.5, 0.0]]])
    ref = stable_three_interpolate(query, known, feat)
    half = stable_three_interpolate(query, known, feat.half())
    assert half.dtype == torch.float16 and torch.isfinite(half).all()
    torch.testing.assert_close(half.float(), ref, atol=2e-3, rtol=2e-3)


def test_three_nn_returns_its_picks_distances_never_below_zero():
    """three_nn gave the search's expanded distance, below 0 for near-coincident points: three_interpolate and
    VoteNet's proposal distance each worked around it on their own."""
    torch.manual_seed(0)
    u = torch.rand(1, 2000, 3) * 4.0
    known = torch.cat([u + torch.randn_like(u) * 1e-4, u], 1)
    dist, idx = ops.three_nn(u, known)
    assert (dist >= 0).all()
    torch.testing.assert_close(dist, ((u[:, :, None] - ops.index_points(known, idx)) ** 2).sum(-1))


@pytest.mark.parametrize("path", ["fast", "portable"])
def test_ball_query_refuses_a_negative_or_nan_radius_and_an_empty_sample(monkeypatch, path):
    """A negative radius was squared into the ball of its absolute value and a NaN one held no point: both
    returned neighbours without a word; nsample 0 gave [B, S, 0] on the torch path and a kernel error on the CPU."""
    monkeypatch.setenv(ops.CPU_PATHS_ENV, path)
    xyz = torch.rand(1, 6, 3)
    for radius in (-0.5, float("nan")):
        with pytest.raises(ValueError, match="radius must be >= 0"):
            ops.ball_query(radius, 3, xyz, xyz[:, :2])
    with pytest.raises(ValueError, match="ball_query: nsample must be an integer >= 1, got 0"):
        ops.ball_query_multi([0.5, 0.5], [3, 0], xyz, xyz[:, :2])
    for k in (2.5, True):  # 2.5 was cut to 2, True taken as 1
        with pytest.raises(ValueError, match=f"ball_query: nsample must be an integer >= 1, got {k}"):
            ops.ball_query(0.5, k, xyz, xyz[:, :2])
    for npoint in (0, 2.5, True):
        with pytest.raises(ValueError, match=f"farthest_point_sample: npoint must be an integer >= 1, got {npoint}"):
            ops.farthest_point_sample(xyz, None, npoint)
    # radius 0 stays valid: the centre itself (drawn from xyz), else its nearest valid point
    assert ops.ball_query(0.0, 2, xyz, xyz[:, :2]).tolist() == [[[0, 0], [1, 1]]]


@pytest.mark.parametrize("path", ["fast", "portable"])
def test_neighbour_searches_refuse_queries_or_masks_of_another_batch(monkeypatch, path):
    """The torch path (CUDA, portable) broadcast centres or a known_mask of batch 1 over a batch of 2 and answered,
    where the C++ kernels refused with 'dst must be float [B, N, 3]'; every path now names the argument."""
    monkeypatch.setenv(ops.CPU_PATHS_ENV, path)
    xyz = torch.rand(2, 6, 3)
    with pytest.raises(ValueError, match="new_xyz must be"):
        ops.ball_query(0.3, 3, xyz, xyz[:1, :2])
    with pytest.raises(ValueError, match="new_xyz must be"):
        ops.knn(2, xyz, xyz[:1, :2])
    with pytest.raises(ValueError, match="unknown must be"):
        ops.three_nn(xyz[:1, :2], xyz)
    with pytest.raises(ValueError, match="known_mask must be"):
        ops.three_nn(xyz[:, :2], xyz, torch.ones(1, 6, dtype=torch.bool))
    with pytest.raises(ValueError, match="known_mask must be"):
        ops.three_interpolate(xyz[:, :2], xyz, torch.rand(2, 6, 1), torch.ones(2, 3, dtype=torch.bool))


#: the torch loop itself, for the stand-in kernel below (the tests replace ``ops.farthest_point_sample_torch``)
_TORCH_FPS = ops.farthest_point_sample_torch


class _CountingKernel:
    """Stands in for the built C++ kernel: counts its FPS calls and answers with the torch loop's indices."""

    def __init__(self) -> None:
        self.calls = 0

    def fps_forward(self, xyz: torch.Tensor, mask: torch.Tensor, npoint: int) -> torch.Tensor:
        self.calls += 1
        return _TORCH_FPS(xyz, mask, npoint)


@pytest.mark.parametrize(
    ("want", "built"),  # FLOAFF_ZOO_FPS_BACKEND=cpp without a kernel is an error (test_fps_force_fallback_env)
    [("auto", True), ("auto", False), ("cpp", True), ("torch", True), ("torch", False)],
    ids=["auto-kernel", "auto-no_kernel", "cpp-kernel", "torch-kernel", "torch-no_kernel"],
)
@pytest.mark.parametrize("paths", ["fast", "portable"])
def test_fps_backend_names_the_implementation_that_ran(paths, want, built, cloud, monkeypatch):
    """fps_backend is printed beside the benchmarks' timings: it must name the FPS that farthest_point_sample
    dispatches to. Under FLOAFF_ZOO_CPU_PATHS=portable the torch loop ran while it said ``cpp``."""
    monkeypatch.setenv(ops.CPU_PATHS_ENV, paths)
    monkeypatch.setenv("FLOAFF_ZOO_FPS_BACKEND", want)
    kernel = _CountingKernel()  # load_kernel hands it out as the built kernel; None with an error: the build failed
    monkeypatch.setitem(_fps_ext._state, "module", kernel if built else None)
    monkeypatch.setitem(_fps_ext._state, "error", None if built else "RuntimeError: no compiler")
    loops = []
    monkeypatch.setattr(ops, "farthest_point_sample_torch", lambda *a: loops.append(a) or _TORCH_FPS(*a))
    xyz, mask = cloud
    assert torch.equal(ops.farthest_point_sample(xyz, mask, 8), _TORCH_FPS(xyz, mask, 8))
    ran = {"cpp": kernel.calls, "torch": len(loops)}
    assert sorted(ran.values()) == [0, 1], ran
    assert ops.fps_backend("cpu") == max(ran, key=ran.get)


def test_gathers_refuse_arguments_of_another_batch_or_shape(monkeypatch):
    """A batch of 1 or a [B, 1, 3] weight was broadcast, and a longer known_feat was read at known's indices."""
    x, f = torch.rand(2, 16, 3), torch.rand(2, 16, 5)
    centres, idx = x[:, :4], torch.zeros(2, 4, 3, dtype=torch.long)
    with pytest.raises(ValueError, match=r"idx \[1, 4\]"):
        ops.index_points(x, torch.zeros(1, 4, dtype=torch.long))
    with pytest.raises(ValueError, match=r"points \[1, 16, 3\]"):
        ops.index_points(x[:1].requires_grad_(), torch.zeros(2, 4, dtype=torch.long))
    monkeypatch.setenv(ops.CPU_PATHS_ENV, "portable")
    with pytest.raises(ValueError, match=r"weight \[2, 1, 3\]"):
        ops.weighted_gather3(f, idx, torch.ones(2, 1, 3))
    for interpolate in (ops.three_interpolate, cfar.stable_three_interpolate):
        with pytest.raises(ValueError, match=r"known_feat must be \[2, 16, C\].*got \[2, 20, 5\]"):
            interpolate(centres, x, torch.rand(2, 20, 5))
        with pytest.raises(ValueError, match=r"known_mask must be \[2, 16\], got \[2, 1\]"):
            interpolate(centres, x, f, known_mask=torch.ones(2, 1, dtype=torch.bool))
        with pytest.raises(ValueError, match=r"unknown must be \[1, S, 3\]"):  # one known point: was expanded
            interpolate(centres, x[:1, :1], f[:1, :1])
    with pytest.raises(ValueError, match=r"known_mask must be \[2, 1\], got \[1, 1\]"):
        ops.three_interpolate(centres, x[:, :1], f[:, :1], torch.ones(1, 1, dtype=torch.bool))
    with pytest.raises(ValueError, match="at least one point"):
        ops.three_interpolate(centres, x[:, :0], f[:, :0])
    for k in (0, -1):
        with pytest.raises(ValueError, match="k must be >= 1"):
            ops.knn(k, x, centres)


def test_canonical_transform_refuses_batch_broadcasts():
    """A [1] angle, a [1, 3] centre, a [B, 1] mask or a batch-1 floor was broadcast over the batch."""
    x, m = torch.rand(2, 16, 3), torch.ones(2, 16, dtype=torch.bool)
    with pytest.raises(ValueError, match=r"angle must be \[2\], got \[1\]"):
        cfar.rotate_z(x, torch.tensor([0.3]))
    with pytest.raises(ValueError, match=r"yaw must be \[4\].*got \[2, 2\]"):
        cfar.alignment_angle(torch.rand(2, 2), 4, x.device, x.dtype)
    with pytest.raises(ValueError, match=r"centre must be \[2, 3\], got \[1, 3\]"):
        cfar.crop_mask(x, m, x[:1, 0], 0.5)
    with pytest.raises(ValueError, match=r"mask must be \[2, 16\], got \[2, 1\]"):
        cfar.crop_mask(x, m[:, :1], x[:, 0], None)
    with pytest.raises(ValueError, match=r"floor_xyz must be \[2, M, 3\]"):
        cfar.canonical_transform(x, m, x[:1], x[:, 0], torch.rand(2), 0.5)
    with pytest.raises(ValueError, match=r"extra_angle must be \[2\]"):
        cfar.canonical_transform(x, m, x, x[:, 0], torch.rand(2), 0.5, extra_angle=torch.rand(1))
    with pytest.raises(ValueError, match=r"centre must be \[2, 3\]"):
        cfar.canonical_to_robot(x, x[:1, 0], torch.rand(2))
    for npoint in (0, 2.5):
        with pytest.raises(ValueError, match=f"tolerant_fps: npoint must be an integer >= 1, got {npoint}"):
            cfar.tolerant_fps(x, m, npoint)
    with pytest.raises(ValueError, match=r"mask must be \[2, 16\]"):
        cfar.tolerant_fps(x, m[:, :1], 4)


def test_placement_and_prior_grid_refuse_broadcast_arguments():
    """A [1] mask or task and a [K, 1] cells were broadcast; xy with a z column had z binned into the inside flag."""
    from floaff_zoo.nn import placement
    from floaff_zoo.nn.prior import CanonicalLabelGrid

    x = torch.rand(16, 3)
    with pytest.raises(ValueError, match=r"mask must be \[16\], got \[1\]"):
        placement.occupied_cells(x, torch.ones(1, dtype=torch.bool))
    with pytest.raises(ValueError, match="occupied_cells: cell must be a finite number > 0, got 0.0"):
        placement.occupied_cells(x, None, cell=0.0)
    with pytest.raises(ValueError, match=r"cells must be \[K, 2\], got \[5, 1\]"):
        placement.footprint_collides(torch.rand(5, 1), torch.rand(3, 3))
    grid = CanonicalLabelGrid(["a", "b"], cell=0.5, extent=1.0, smooth_sigma_cells=0)
    xy, label, mask = torch.rand(2, 5, 2), torch.rand(2, 5), torch.ones(2, 5, dtype=torch.bool)
    with pytest.raises(ValueError, match=r"task must be \[2\].*got \[1\]"):
        grid.add(torch.tensor([1]), xy, label, mask)
    with pytest.raises(ValueError, match=r"mask must be \[2, 5\], got \[2, 1\]"):
        grid.add(torch.tensor([0, 1]), xy, label, mask[:, :1])
    with pytest.raises(ValueError, match=r"task indices must be in \[0, 2\)"):
        grid.add(torch.tensor([2, 0]), xy, label, mask)
    with pytest.raises(ValueError, match=r"xy must be \[B, M, 2\]"):
        grid.read(torch.tensor([0, 1]), torch.rand(2, 5, 3))
    with pytest.raises(ValueError, match=r"task must be \[2\]"):
        grid.read(torch.tensor([1]), xy)
    assert grid.counts.sum() == 0  # nothing was added by the refused calls


_B = (torch.rand(2, 16, 3), torch.ones(2, 16, dtype=torch.bool), torch.rand(2, 4, 2), torch.rand(2, 2))
_NAN = float("nan")


@pytest.mark.parametrize(
    ("call", "message"),
    [
        # each ran: a NaN size, fraction or height put no point inside or kept none (free / nothing counted)
        (lambda p: p.occupied_cells(torch.rand(8, 3), None, 0.1, _NAN), r"occupied_cells: z_min must be a finite"),
        (lambda p: p.occupied_cells(torch.rand(8, 3), None, True), r"occupied_cells: cell must be .* got True"),
        (lambda p: p.footprint_collides(torch.rand(4, 2), torch.rand(3, 3), _NAN), r"collides: length must be"),
        (lambda p: p.footprint_collides(torch.rand(4, 2), torch.rand(3, 3), width=-1.0), r"collides: width must be"),
        (
            lambda p: p.footprint_collides(torch.rand(4, 2), torch.rand(3, 3), back_frac=2.0),
            r"back_frac must be .*<= 1",
        ),
        (lambda p: p.footprint_counts(*_B, footprint=(_NAN, 0.5, 0.1)), r"counts: footprint length must be a finite"),
        (
            lambda p: p.footprint_counts(*_B, footprint=(0.6, 0.5)),
            r"counts: footprint must be \(length, width, front\)",
        ),
        (lambda p: p.footprint_counts(*_B, z_range=(_NAN, 1.0)), r"counts: z_range low must be a finite number"),
        (lambda p: p.footprint_counts(*_B, z_range=(1.0, 0.1)), r"counts: z_range must have low < high"),
        (lambda p: p.footprint_counts(*_B, chunk=-3), r"footprint_counts: chunk must be an integer >= 1, got -3"),
        (lambda p: p.footprint_counts(*_B, chunk=2.5), r"footprint_counts: chunk must be an integer >= 1, got 2.5"),
        # these failed in math.ceil / torch.zeros naming no argument
        (lambda p: p.footprint_seen(*_B, footprint=(_NAN, 0.5, 0.1)), r"seen: footprint length must be a finite"),
        (lambda p: p.footprint_seen(*_B, footprint=(0.6, -0.5, 0.1)), r"seen: footprint width must be a finite"),
        (lambda p: p.footprint_seen(*_B, chunk=0), r"footprint_seen: chunk must be an integer >= 1, got 0"),
    ],
)
def test_placement_refuses_bad_sizes_by_name(call, message):
    from floaff_zoo.nn import placement

    with pytest.raises(ValueError, match=message):
        call(placement)
