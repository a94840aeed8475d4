"""Friends-of-friends clustering (paper Algorithm 2): connected components of the ε-neighbour graph.

Two points are friends when their distance is below ε; clusters are the transitive closure of
friendship; a point without friends is noise. The result is a partition, independent of any
visiting order, so it can be computed far faster than the paper's breadth-first traversal:

1. Points are binned into cubic cells of side slightly below ε/√3. A cell's diagonal is then
   below ε, so all points in one cell are mutual friends: each cell is a clique and is merged
   for free. Occupied cells are found through a bitmap (one 64-bit word per 64 cells along the
   longest axis, plus a prefix count), so a neighbour lookup is a gather and a popcount.
2. Two different cells can only hold friends when their offset is within ±2 cells on every axis
   (2 cells < ε < 3 cells): 62 "half offsets". Touching cells (13 offsets) are checked for every
   cell, faces first; along the bitmap's axis linked runs of cells are labelled by a cumulative
   sum. After each batch the cell graph's components are refreshed (scipy connected_components)
   and a cell pair already in one component is skipped without looking at its points.
3. The farther offsets are only needed near a boundary between components: cells are grouped in
   4x4x4 blocks, and a cell is skipped when its block and the 26 blocks around it (which cover
   its ±2 neighbourhood) hold only its own component. Small fragments first look in every far
   direction (a shortcut that only adds true links), then the exact sweep runs on what is left.
4. A candidate cell pair is linked when their first points are friends, else when any of their
   point pairs are (compared exhaustively; cells hold a handful of points).

Distance comparison: friends when ``d² < ε²`` (``inclusive=False``, the paper's "less than ε" and
Open3D ``cluster_dbscan``'s rule) or ``d² <= ε²`` (``inclusive=True``, scipy ``query_pairs``'s rule),
with ``d²`` and ``ε²`` computed in float64 exactly as those libraries do, so ties at exactly ε
come out the same.
"""

from __future__ import annotations

import logging
import time

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

log = logging.getLogger(__name__)

# Cells are eps/sqrt(3) shrunk by this factor so that rounding in the binning can never put two
# points farther apart than eps into one cell.
_CELL_SHRINK = 1.0 - 1e-7
# Largest occupancy bitmap (64-cell words, 16 bytes each with the prefix counts); larger
# scenes (far outliers, huge extents) fall back to the kd-tree path.
_MAX_WORDS = 40_000_000
# Point pairs compared at once in the exact test (bounds memory).
_PAIR_CHUNK = 4_000_000


def _half_offsets() -> list[list[tuple[int, int, int]]]:
    """Cell offsets (one of each ± pair) that can hold friends, grouped nearest first."""
    offs = []
    for dx in range(-2, 3):
        for dy in range(-2, 3):
            for dz in range(-2, 3):
                o = (dx, dy, dz)
                if o == (0, 0, 0) or o < (0, 0, 0):
                    continue
                offs.append(o)
    # Batches: faces; other touching cells; then by how many axes are two cells away.
    faces = [o for o in offs if sum(abs(v) for v in o) == 1]
    touching = [o for o in offs if max(abs(v) for v in o) == 1 and o not in faces]
    far = [o for o in offs if max(abs(v) for v in o) == 2]
    far1 = [o for o in far if sum(abs(v) == 2 for v in o) == 1]
    far2 = [o for o in far if sum(abs(v) == 2 for v in o) == 2]
    far3 = [o for o in far if sum(abs(v) == 2 for v in o) == 3]
    return [faces, touching, far1, far2 + far3]


_BATCHES = _half_offsets()
_FAR_HALF = _BATCHES[2] + _BATCHES[3]
_FAR_BOTH = _FAR_HALF + [(-a, -b, -c) for a, b, c in _FAR_HALF]
# Components of at most this many cells after the touching pass take the shortcut pass.
_SMALL_COMPONENT_CELLS = 8
_ONE = np.uint64(1)


class _Lap:
    """Debug log of the CPU time each step of ``fof_clusters`` took."""

    def __init__(self) -> None:
        self.t = time.process_time()

    def __call__(self, what: str) -> None:
        if log.isEnabledFor(logging.DEBUG):
            t = time.process_time()
            log.debug("fof %s: %.1f ms cpu", what, 1000 * (t - self.t))
            self.t = t


class _Cells:
    """The occupied grid cells, points sorted by cell: order (N,) point index by sorted position; starts,
    counts (ncell,) each cell's run in that order; cell_keys (ncell,) linear keys in a padded grid of
    ``dims`` cells; cell_of_sorted (N,) cell of each sorted point; first_xyz (ncell, 3) one point per cell (m)."""

    def __init__(self, p: np.ndarray, q: list[np.ndarray], size: np.ndarray):
        n = len(p)
        # The longest axis becomes the bit axis of the occupancy words (fewest words).
        perm = np.argsort(size, kind="stable")
        self.dims = dims = size[perm] + 4  # +2 padding each side
        self.n_words = _grid_words(size)
        # +2: offsets never go below 0.
        key = q[perm[0]] + 2
        for ax in (1, 2):
            key *= dims[ax]
            key += q[perm[ax]] + 2
        # Sort (key, index) packed in one int64: a plain sort is several times faster than argsort.
        key *= n
        key += np.arange(n, dtype=np.int64)
        packed = key
        del key
        packed.sort()
        sk = packed // n
        self.order = packed - sk * n
        del packed
        new_cell = np.empty(n, dtype=bool)
        new_cell[0] = True
        np.not_equal(sk[1:], sk[:-1], out=new_cell[1:])
        self.starts = np.flatnonzero(new_cell)
        self.ncell = len(self.starts)
        self.cell_of_sorted = np.cumsum(new_cell, dtype=np.int64) - 1
        del new_cell
        self.cell_keys = sk[self.starts]
        self.counts = np.diff(np.append(self.starts, n))
        self.first_xyz = p[self.order[self.starts]]   # one point per cell, for the cheap first test


class _Occupancy:
    """Occupancy bitmap of the cells: one uint64 word per 64 cells along the bit axis, plus the number of
    occupied cells before each word, which is the sorted cell index of the word's first cell.
    ``lookup`` finds each cell's occupied neighbour at an offset by a gather and a popcount."""

    def __init__(self, cells: _Cells):
        dims, cell_keys = cells.dims, cells.cell_keys
        self.cell_keys = cell_keys
        self.W = W = (dims[2] + 63) // 64
        qab = cell_keys // dims[2]
        self.qc = qc = cell_keys - qab * dims[2]
        self.word_base = word_base = qab * W
        word_of_cell = word_base + (qc >> 6)
        bit_of_cell = (qc & 63).astype(np.uint64)
        self.words = words = np.zeros(cells.n_words, dtype=np.uint64)
        wstart = np.flatnonzero(np.r_[True, word_of_cell[1:] != word_of_cell[:-1]])
        words[word_of_cell[wstart]] = np.bitwise_or.reduceat(np.left_shift(np.uint64(1), bit_of_cell), wstart)
        self.prefix = np.zeros(cells.n_words, dtype=np.int64)
        self.prefix[word_of_cell[wstart]] = wstart
        # Empty words need no prefix: a lookup that lands in one finds its bit unset.
        # Per cell: its word and the mask selecting its bit, so that offsets staying on the same bit
        # (dc = 0) cost one gather and a popcount.
        self.word_of_cell = word_of_cell
        self.bit_sel = np.left_shift(_ONE, (qc & 63).astype(np.uint64))
        self.base_lin = dims[1] * W
        self._shifted_cache: dict = {}

    def lookup(self, sel: np.ndarray | None, off) -> tuple[np.ndarray, np.ndarray]:
        """(cells, neighbours): occupied neighbour of each cell (or of cells[sel]) at offset off."""
        da, db, dc = off
        if sel is None and da == 0 and db == 0:
            # Along the bit axis the neighbour, if any, is among the next cells in sorted order.
            cells_, nbs_ = [], []
            for k in range(1, dc + 1):
                i = np.flatnonzero(self.cell_keys[k:] == self.cell_keys[:-k] + dc)
                cells_.append(i)
                nbs_.append(i + k)
            return np.concatenate(cells_), np.concatenate(nbs_)
        if sel is None:
            # Every cell: the neighbour's bit is this cell's bit shifted by dc within the same
            # word, except for the few cells at a word's edge, which take the general path.
            bs, cross = self._shifted(dc)
            w = self.word_of_cell + (da * self.base_lin + db * self.W)
            bits = self.words[w]
            occ = (bits & bs) != 0
            if cross is not None:
                occ[cross] = False
            cells = np.flatnonzero(occ)
            nb = self.prefix[w[cells]] + np.bitwise_count(bits[cells] & (bs[cells] - _ONE))
            if cross is not None and len(cross):
                c2, n2 = self._general(cross, da, db, dc)
                cells = np.concatenate([cells, c2])
                nb = np.concatenate([nb.astype(np.int64), n2])
            return cells, nb.astype(np.int64)
        return self._general(sel, da, db, dc)

    def _shifted(self, dc: int):
        """(each cell's bit shifted by dc along the bit axis, the cells whose shift leaves their word), cached."""
        if dc not in self._shifted_cache:
            if dc == 0:
                self._shifted_cache[dc] = (self.bit_sel, None)
            else:
                bit = self.qc & 63
                bs = (np.left_shift(self.bit_sel, np.uint64(dc)) if dc > 0
                      else np.right_shift(self.bit_sel, np.uint64(-dc)))
                self._shifted_cache[dc] = (bs, np.flatnonzero((bit + dc < 0) | (bit + dc > 63)))
        return self._shifted_cache[dc]

    def _general(self, sel: np.ndarray, da: int, db: int, dc: int) -> tuple[np.ndarray, np.ndarray]:
        """(cells, neighbours) at offset (da, db, dc) for the cells sel, by their word and bit one by one."""
        zc = self.qc[sel] + dc
        w = self.word_base[sel] + (da * self.base_lin + db * self.W) + (zc >> 6)
        bits = self.words[w]
        b = (zc & 63).astype(np.uint64)
        occ = ((bits >> b) & _ONE).astype(bool)
        cells = sel[occ]
        bits = bits[occ]
        b = b[occ]
        nb = self.prefix[w[occ]] + np.bitwise_count(bits & ((_ONE << b) - _ONE))
        return cells, nb.astype(np.int64)


class _Linker:
    """Components of the cell graph: candidate cell pairs are linked when any of their points are friends.

    comp (ncell,): component of each cell; links found by ``link`` are merged by ``refresh``.
    """

    def __init__(self, p: np.ndarray, cells: _Cells, occupancy: _Occupancy, eps2: float, inclusive: bool):
        self.p, self.cells, self.occ, self.eps2, self.inclusive = p, cells, occupancy, eps2, inclusive
        self.comp = np.arange(cells.ncell, dtype=np.int64)
        self.edges_a: list[np.ndarray] = []
        self.edges_b: list[np.ndarray] = []

    def first_points_friends(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Cheap check on the first point of each cell of the pairs (a, b)."""
        d = self.cells.first_xyz[a] - self.cells.first_xyz[b]
        d2 = np.einsum("ij,ij->i", d, d)
        return d2 <= self.eps2 if self.inclusive else d2 < self.eps2

    def any_friends(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Exhaustive check over the point pairs of each cell pair (a, b)."""
        c = self.cells
        return _any_pair_within(self.p, c.order, c.starts, c.counts, a, b, self.eps2, self.inclusive)

    def refresh(self) -> None:
        """Merge the components joined by the edges found since the last refresh."""
        if not self.edges_a:
            return
        comp = self.comp
        ea = comp[np.concatenate(self.edges_a)]
        eb = comp[np.concatenate(self.edges_b)]
        self.edges_a, self.edges_b = [], []
        if len(ea) == 0:
            return
        k = int(comp.max()) + 1
        g = coo_matrix((np.ones(len(ea), dtype=np.int8), (ea, eb)), shape=(k, k)).tocsr()
        self.comp = connected_components(g, directed=True, connection="weak")[1].astype(np.int64)[comp]

    def link(self, sel: np.ndarray | None, offsets) -> None:
        """Find the links of the cells (all, or ``sel``) to their neighbours at ``offsets`` in other components."""
        for off in offsets:
            a, b = self.occ.lookup(sel, off)
            if len(a) == 0:
                continue
            diff = self.comp[a] != self.comp[b]
            a, b = a[diff], b[diff]
            if len(a) == 0:
                continue
            hit = self.first_points_friends(a, b)
            self.edges_a.append(a[hit])
            self.edges_b.append(b[hit])
            a, b = a[~hit], b[~hit]
            if len(a) == 0:
                continue
            linked = self.any_friends(a, b)
            self.edges_a.append(a[linked])
            self.edges_b.append(b[linked])

    def link_runs(self) -> None:
        """Faces along the bit axis: consecutive linked cells form runs, labelled by a cumsum (no graph needed)."""
        a, b = self.occ.lookup(None, (0, 0, 1))
        hit = self.first_points_friends(a, b)
        rest = ~hit
        if rest.any():
            hit[rest] = self.any_friends(a[rest], b[rest])
        joined = np.zeros(self.cells.ncell, dtype=bool)
        joined[b[hit]] = True          # b = a + 1 in sorted order: joined to its predecessor
        self.comp = np.cumsum(~joined) - 1


def _link_cells(p: np.ndarray, cells: _Cells, eps2: float, inclusive: bool, lap: _Lap) -> np.ndarray:
    """Component (ncell,) of each occupied cell: the three linking passes over the occupancy bitmap."""
    linker = _Linker(p, cells, _Occupancy(cells), eps2, inclusive)
    # Pass 1: cells sharing a face, then the other touching cells (every cell); the refresh
    # between them lets most of the second batch be skipped as already joined.
    lap("occupancy bitmap")
    linker.link_runs()  # the other two face directions then join runs
    linker.link(None, [o for o in _BATCHES[0] if o != (0, 0, 1)])
    linker.refresh()
    lap("faces")
    linker.link(None, _BATCHES[1])
    linker.refresh()
    lap("other touching")
    # Pass 2 (a shortcut, adds only true links): cells of small components look in every far
    # direction, which absorbs most fragments into their surface's component.
    comp = linker.comp
    csize = np.bincount(comp, minlength=cells.ncell)
    small = np.flatnonzero(csize[comp] <= _SMALL_COMPONENT_CELLS)
    if len(small):
        linker.link(small, _FAR_BOTH)
        linker.refresh()
    # Pass 3 (the exact sweep): every far half offset from each cell that may still have a
    # friend in another component.
    lap(f"small components ({len(small)} cells)")
    sel = _active_cells(cells.cell_keys, cells.dims, linker.comp)
    lap(f"active cells ({len(sel)} of {cells.ncell})")
    if len(sel):
        linker.link(sel, _FAR_HALF)
        linker.refresh()
    lap("far offsets")
    return linker.comp


def _cell_indices(p: np.ndarray, eps_m: float, allow_split: bool, inclusive: bool, lap: _Lap):
    """Integer cell coordinates of the points, or the components by another path when the grid cannot be built.

    Returns ("grid", q, size) with q three (N,) int64 arrays and size (3,) cells per axis, or
    ("components", comp) when far-flung points are clustered separately or the kd-tree path is taken.
    """
    cell = float(eps_m) / np.sqrt(3.0) * _CELL_SHRINK
    # Per-column reductions: numpy's axis-0 reduction of an (N, 3) array is several times slower.
    lo = np.array([p[:, i].min() for i in range(3)])
    ext = (np.array([p[:, i].max() for i in range(3)]) - lo) / cell
    if np.any(ext > 1.0e12):
        log.debug("fof: absurd extent, using the kd-tree path")
        return ("components", _scipy_components(p, eps_m, inclusive))
    # Cell index per point and axis; (p - lo) >= 0, so truncation is floor.
    inv = 1.0 / cell
    q = [((p[:, ax] - lo[ax]) * inv).astype(np.int64) for ax in range(3)]
    size = np.array([int(qa.max()) + 1 for qa in q])
    n = len(p)
    if not _grid_ok(size, n) and allow_split:
        comp_ = _split_far_points(p, eps_m, inclusive)
        if comp_ is not None:
            return ("components", comp_)
    if not _grid_ok(size, n):
        # Far-flung points (sky noise, a distant building) would make the grid huge: squeeze
        # every empty stretch of 3 or more cells to 3. Cells 3 apart can never hold friends
        # (2 cells > ε), and nearer ones keep their exact offsets, so the partition is unchanged.
        for ax in range(3):
            q[ax], size[ax] = _squeeze_axis(q[ax])
        lap("squeezed empty stretches")
        if not _grid_ok(size, n):
            log.debug("fof: occupied grid too large even squeezed, using the kd-tree path")
            return ("components", _scipy_components(p, eps_m, inclusive))
    return ("grid", q, size)


def fof_clusters(points: np.ndarray, eps_m: float, min_size: int = 2, inclusive: bool = False, *,
                 _components: bool = False, _allow_split: bool = True) -> np.ndarray:
    """Friends-of-friends cluster labels.

    points: (N, 3) coordinates in metres (any frame). eps_m: friendship distance ε in metres.
    min_size: clusters with fewer points get label -1 (default 2: points without friends are noise).
    inclusive: friends when d <= ε instead of d < ε.
    Returns (N,) int64 labels: 0 is the largest cluster, then decreasing size; -1 is noise.
    """
    p = np.ascontiguousarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {p.shape}")
    n = len(p)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if not (eps_m > 0 and np.isfinite(eps_m)):
        raise ValueError(f"eps_m must be a positive finite number, got {eps_m}")
    eps2 = float(eps_m) * float(eps_m)
    lap = _Lap()
    grid = _cell_indices(p, eps_m, _allow_split, inclusive, lap)
    if grid[0] == "components":
        return grid[1] if _components else _relabel(grid[1], np.ones(n), min_size)
    cells = _Cells(p, grid[1], grid[2])
    del grid
    lap("binning and sort")
    comp = _link_cells(p, cells, eps2, inclusive, lap)
    # Relabel at the cell level (sizes counted in points), then spread to the points.
    if _components:
        out = np.empty(n, dtype=np.int64)
        out[cells.order] = comp[cells.cell_of_sorted]
        return out
    cell_label = _relabel(comp, cells.counts, min_size)
    labels = np.empty(n, dtype=np.int64)
    labels[cells.order] = cell_label[cells.cell_of_sorted]
    lap("labels")
    return labels


def _grid_words(size: np.ndarray) -> int:
    """Occupancy words for a grid of ``size`` cells (+2 padding each side; bit axis the longest)."""
    d = np.sort(np.asarray(size, dtype=np.int64)) + 4
    return int(d[0] * d[1] * ((d[2] + 63) // 64))


def _grid_ok(size: np.ndarray, n: int) -> bool:
    """The bitmap fits in memory and (cell key, point index) packs into an int64."""
    return _grid_words(size) <= _MAX_WORDS and float(np.prod(size.astype(float) + 4)) * n < 2.0**62


def _squeeze_axis(q: np.ndarray) -> tuple[np.ndarray, int]:
    """Renumber cell indices so every gap of 3 or more empty cells becomes exactly 3."""
    r = int(q.max()) + 1
    if r <= 5_000_000:
        occ = np.flatnonzero(np.bincount(q, minlength=r))
    else:
        occ = np.unique(q)
    gaps = np.minimum(np.diff(occ), 3)
    newpos = np.concatenate([[0], np.cumsum(gaps)])
    if r <= 5_000_000:
        lut = np.zeros(r, dtype=np.int64)
        lut[occ] = newpos
        return lut[q], int(newpos[-1]) + 1
    return newpos[np.searchsorted(occ, q)], int(newpos[-1]) + 1


def _relabel(comp: np.ndarray, weight: np.ndarray, min_size: int) -> np.ndarray:
    """Labels 0.. by decreasing size (ties: smallest first member), size < min_size -> -1."""
    k = int(comp.max()) + 1 if len(comp) else 0
    size = np.bincount(comp, weights=weight, minlength=k).astype(np.int64)
    first = np.full(k, len(comp), dtype=np.int64)
    np.minimum.at(first, comp, np.arange(len(comp)))
    present = size > 0
    ids = np.flatnonzero(present)
    order = ids[np.lexsort((first[ids], -size[ids]))]
    rank = np.full(k, -1, dtype=np.int64)
    rank[order] = np.arange(len(order))
    rank[size < min_size] = -1
    return rank[comp]


def _active_cells(cell_keys: np.ndarray, dims: np.ndarray, comp: np.ndarray) -> np.ndarray:
    """Cells that may still have a friend in another component within ±2 cells.

    Blocks of 4x4x4 cells cover any cell's ±2 neighbourhood with the block and its 26 neighbours;
    a cell is settled when all those blocks hold only its own component.
    """
    qa = cell_keys // (dims[1] * dims[2])
    rem = cell_keys - qa * (dims[1] * dims[2])
    qb = rem // dims[2]
    qc = rem - qb * dims[2]
    bdims = dims // 4 + 3
    bkey = ((qa >> 2) + 1) * (bdims[1] * bdims[2]) + ((qb >> 2) + 1) * bdims[2] + ((qc >> 2) + 1)
    # Per-block min/max component from one sort of (block, component) packed in an int64.
    ncomp = int(comp.max()) + 1
    packed = np.sort(bkey * ncomp + comp)
    pb = packed // ncomp
    first = np.flatnonzero(np.r_[True, pb[1:] != pb[:-1]])
    last = np.r_[first[1:] - 1, len(pb) - 1]
    ub = pb[first]
    cmin = packed[first] - ub * ncomp
    cmax = packed[last] - ub * ncomp
    nb = len(ub)
    bad = cmin != cmax
    n_grid = int(bdims[0] * bdims[1] * bdims[2])
    grid = None
    if n_grid <= 32_000_000:
        grid = np.full(n_grid, -1, dtype=np.int32 if nb < 2**31 else np.int64)
        grid[ub] = np.arange(nb)
    for da in (-1, 0, 1):
        for db in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if da == db == dc == 0:
                    continue
                k2 = ub + (da * bdims[1] + db) * bdims[2] + dc
                if grid is not None:
                    j = grid[k2].astype(np.int64)
                    found = j >= 0
                else:
                    j = np.searchsorted(ub, k2)
                    j[j >= nb] = nb - 1
                    found = ub[j] == k2
                jj = j[found]
                bad[found] |= (cmin[jj] != cmin[found]) | (cmax[jj] != cmin[found])
    binv = grid[bkey] if grid is not None else np.searchsorted(ub, bkey)
    return np.flatnonzero(bad[binv])


def _any_pair_within(p, order, starts, counts, a, b, eps2, inclusive) -> np.ndarray:
    """For cell pairs (a[k], b[k]): does any point of cell a lie within ε of any point of cell b?"""
    out = np.zeros(len(a), dtype=bool)
    na = counts[a]
    nb = counts[b]
    npair = na * nb
    # Chunk over cell pairs so the expanded point pairs stay bounded.
    cum = np.cumsum(npair)
    begin = 0
    while begin < len(a):
        base = cum[begin - 1] if begin else 0
        end = int(np.searchsorted(cum, base + _PAIR_CHUNK, side="right"))
        end = max(end, begin + 1)
        sl = slice(begin, end)
        m = npair[sl]
        k = np.repeat(np.arange(end - begin), m)
        first = np.cumsum(m) - m
        t = np.arange(len(k)) - first[k]
        nbk = nb[sl][k]
        i = starts[a[sl]][k] + t // nbk
        j = starts[b[sl]][k] + t % nbk
        d = p[order[i]] - p[order[j]]
        d2 = np.einsum("ij,ij->i", d, d)
        hit = d2 <= eps2 if inclusive else d2 < eps2
        out[sl] = np.bincount(k[hit], minlength=end - begin) > 0
        begin = end
    return out


def _split_far_points(p: np.ndarray, eps_m: float, inclusive: bool, far_share: float = 0.05) -> np.ndarray | None:
    """Components when a few far-flung points blow up the grid: the grid path on the core box,
    a kd-tree on the points outside it plus the core points within ε of its faces, then one
    union of the two graphs. None when more than ``far_share`` of the points lie outside."""
    from scipy.spatial import cKDTree

    n = len(p)
    lo_q = np.array([np.quantile(p[:, i], 0.005) for i in range(3)])
    hi_q = np.array([np.quantile(p[:, i], 0.995) for i in range(3)])
    margin = 0.1 * (hi_q - lo_q) + 2 * eps_m
    lo_b, hi_b = lo_q - margin, hi_q + margin
    inside = np.all((p >= lo_b) & (p <= hi_b), axis=1)
    core_idx = np.flatnonzero(inside)
    out_idx = np.flatnonzero(~inside)
    if len(out_idx) == 0 or len(out_idx) > far_share * n:
        return None
    core = p[core_idx]
    comp_core = fof_clusters(core, eps_m, inclusive=inclusive, _components=True, _allow_split=False)
    # Any friend of an outside point that is inside lies within ε of the box's faces.
    band = np.flatnonzero(np.any((core - lo_b <= eps_m) | (hi_b - core <= eps_m), axis=1))
    s_idx = np.concatenate([out_idx, core_idx[band]])
    k = int(comp_core.max()) + 1 if len(comp_core) else 0
    node = np.concatenate([k + np.arange(len(out_idx)), comp_core[band]])
    pairs = cKDTree(p[s_idx]).query_pairs(float(eps_m), output_type="ndarray")
    if not inclusive and len(pairs):
        d = p[s_idx[pairs[:, 0]]] - p[s_idx[pairs[:, 1]]]
        pairs = pairs[np.einsum("ij,ij->i", d, d) < float(eps_m) * float(eps_m)]
    m = k + len(out_idx)
    g = coo_matrix((np.ones(len(pairs), dtype=np.int8), (node[pairs[:, 0]], node[pairs[:, 1]])), shape=(m, m)).tocsr()
    cc = connected_components(g, directed=True, connection="weak")[1].astype(np.int64)
    comp = np.empty(n, dtype=np.int64)
    comp[core_idx] = cc[comp_core]
    comp[out_idx] = cc[k + np.arange(len(out_idx))]
    return comp


def _scipy_components(p: np.ndarray, eps_m: float, inclusive: bool) -> np.ndarray:
    """Component id per point from scipy query_pairs + connected_components."""
    from scipy.spatial import cKDTree

    n = len(p)
    pairs = cKDTree(p).query_pairs(float(eps_m), output_type="ndarray")
    if not inclusive and len(pairs):
        d = p[pairs[:, 0]] - p[pairs[:, 1]]
        pairs = pairs[np.einsum("ij,ij->i", d, d) < float(eps_m) * float(eps_m)]
    g = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    return connected_components(g, directed=True, connection="weak")[1].astype(np.int64)


def fof_reference_scipy(points: np.ndarray, eps_m: float, min_size: int = 2, inclusive: bool = False) -> np.ndarray:
    """FoF by scipy ``cKDTree.query_pairs`` + ``connected_components`` (slow reference, same labels rule).

    ``query_pairs`` keeps pairs with ``d² <= ε²``; for ``inclusive=False`` pairs at exactly ε are dropped.
    """
    from scipy.spatial import cKDTree

    p = np.ascontiguousarray(points, dtype=np.float64)
    n = len(p)
    pairs = cKDTree(p).query_pairs(float(eps_m), output_type="ndarray")
    if not inclusive and len(pairs):
        d = p[pairs[:, 0]] - p[pairs[:, 1]]
        d2 = np.einsum("ij,ij->i", d, d)
        pairs = pairs[d2 < float(eps_m) * float(eps_m)]
    g = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    _, comp = connected_components(g, directed=True, connection="weak")
    return _relabel(comp.astype(np.int64), np.ones(n), min_size)


def same_partition(labels_a: np.ndarray, labels_b: np.ndarray) -> bool:
    """True when two labelings describe the same partition (label values may differ; -1 must match -1)."""
    a = np.asarray(labels_a)
    b = np.asarray(labels_b)
    if a.shape != b.shape:
        return False
    if not np.array_equal(a < 0, b < 0):
        return False
    m = a >= 0
    a, b = a[m], b[m]
    if len(a) == 0:
        return True
    pairs = np.unique(np.stack([a, b], axis=1), axis=0)
    return len(pairs) == len(np.unique(a)) == len(np.unique(b))
