"""DBSCAN and HDBSCAN as scikit-learn defines them (Euclidean; HDBSCAN with alpha 1, excess-of-mass
selection, no single cluster), in numpy alone: the labelling policies call them instead of
`sklearn.cluster`, whose import costs about 1 s (it loads scipy.stats and pandas).

The labels equal scikit-learn's 1.9 label for label, numbering included (tests/test_density.py): every
distance is computed as scikit-learn's neighbour trees and Prim's algorithm compute it (the squared
coordinate differences summed in column order, then the square root), and every tie is broken as
scikit-learn breaks it (the order of the spanning tree's edges, of the tree walks and of the sums).
Two exceptions: scikit-learn's DBSCAN on 11 rows or fewer, or on more than 15 columns, finds neighbours
by brute force through the expansion |a|^2 - 2 a.b + |b|^2, whose rounding may put a pair lying within
a rounding error of eps on the other side (here: the exact sum, as its k-d tree); and its HDBSCAN with
cluster_selection_epsilon fails (a TypeError under numpy 2.4) where the epsilon search climbs more than
one level of the tree, where this one returns what that search means to return.

Nothing builds an n x n matrix, nor keeps the pairs within reach: distances are taken for the points
of one k-d tree leaf against the leaves within reach, or one row at a time (Prim's algorithm).
"""

from __future__ import annotations

import numpy as np


def _sq_dists(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(len(rows), n) squared distances from `rows` (m, d) to the points `cols` (d, n), summed column by
    column in order, as scikit-learn's trees sum them (so equal inputs give bit-equal distances)."""
    out = np.subtract.outer(rows[:, 0], cols[0])
    out *= out
    tmp = np.empty_like(out)
    for k in range(1, cols.shape[0]):
        np.subtract.outer(rows[:, k], cols[k], out=tmp)
        tmp *= tmp
        out += tmp
    return out


def _sum_sq(gap: np.ndarray) -> np.ndarray:
    """Squares of the last axis summed in column order (as `_sq_dists` sums them)."""
    out = gap[..., 0] * gap[..., 0]
    for k in range(1, gap.shape[-1]):
        out += gap[..., k] * gap[..., k]
    return out


class _Leaves:
    """The points cut into leaves of at most SIZE by repeated median splits of the widest column (a
    k-d tree's leaves), kept leaf after leaf, with each leaf's bounding box.  A leaf needs distances only
    to the leaves whose box lies within the search radius of its own: a box gap never exceeds a
    distance, and stays below it once rounded, as every term of the sum is rounded the same way."""

    SIZE = 64
    FIRST = 192  # points searched first for a k-nearest bound

    def __init__(self, x: np.ndarray):
        parts, todo = [], [np.arange(x.shape[0])]
        while todo:
            ids = todo.pop()
            if ids.size <= self.SIZE:
                parts.append(ids)
                continue
            col = x[ids, int(np.argmax(np.ptp(x[ids], axis=0)))]
            half = ids.size // 2
            split = np.argpartition(col, half)
            todo += [ids[split[half:]], ids[split[:half]]]
        self.order = np.concatenate(parts)
        self.x = x[self.order]
        self.cols = np.ascontiguousarray(self.x.T)
        self.start = np.cumsum([0] + [p.size for p in parts])
        self.low = np.array([x[p].min(axis=0) for p in parts])
        self.high = np.array([x[p].max(axis=0) for p in parts])

    def leaves(self):
        return range(self.start.size - 1)

    def box_gaps(self, leaf: int) -> np.ndarray:
        """Squared distance from leaf's box to every leaf's box (0 where they overlap)."""
        return _sum_sq(np.maximum(np.maximum(self.low - self.high[leaf], self.low[leaf] - self.high), 0.0))

    def point_gaps(self, leaf: int) -> np.ndarray:
        """(rows, leaves) squared distance from each of leaf's points to every leaf's box."""
        p = self.x[self.rows(leaf)][:, None, :]
        return _sum_sq(np.maximum(np.maximum(self.low[None] - p, p - self.high[None]), 0.0))

    def rows(self, leaf: int) -> slice:
        return slice(int(self.start[leaf]), int(self.start[leaf + 1]))

    def points(self, leaves: np.ndarray) -> np.ndarray:
        """Positions (in leaf order) of the points of `leaves`."""
        return np.concatenate([np.arange(self.start[i], self.start[i + 1]) for i in leaves.tolist()])

    def sq_dists(self, leaf: int, pos: np.ndarray) -> np.ndarray:
        return _sq_dists(self.x[self.rows(leaf)], self.cols[:, pos])


def dbscan(x: np.ndarray, eps: float, min_samples: int) -> np.ndarray:
    """`sklearn.cluster.DBSCAN(eps=eps, min_samples=min_samples).fit_predict(x)`: labels (-1 noise).

    A neighbour lies within eps (squared distance <= eps**2, the point itself included); a point with at
    least min_samples neighbours is a core point.  Clusters are the connected components of the core
    points, numbered in the order of their lowest-index core point; scikit-learn grows them one after
    the other, so a border point next to several clusters joins the lowest numbered.  Each cluster is
    grown breadth-first here, a frontier point's distances taken to the unlabelled points of the
    leaves within eps of its own (no neighbour lists are kept)."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    if n == 0:
        return np.full(0, -1, dtype=np.int64)
    t = _Leaves(x)
    r2 = float(eps) * float(eps)
    reach = [t.points(np.flatnonzero(t.box_gaps(leaf) <= r2)) for leaf in t.leaves()]
    counts = np.concatenate([np.count_nonzero(t.sq_dists(leaf, reach[leaf]) <= r2, axis=1) for leaf in t.leaves()])
    core = counts >= min_samples  # by position in leaf order, as everything below
    leaf_of = np.repeat(np.arange(len(reach)), np.diff(t.start))
    where = np.argsort(t.order)  # position of each point
    labels = np.full(n, -1, dtype=np.int64)
    cluster = 0
    for seed in where[np.sort(t.order[core])]:  # core points in index order
        if labels[seed] != -1:
            continue
        labels[seed] = cluster
        frontier = np.array([seed])
        while frontier.size:  # the unlabelled neighbours of the frontier's core points, leaf by leaf
            found = []
            for leaf in np.unique(leaf_of[frontier]).tolist():
                free = reach[leaf][labels[reach[leaf]] == -1]
                if free.size:
                    rows = t.x[frontier[leaf_of[frontier] == leaf]]
                    new = free[(_sq_dists(rows, t.cols[:, free]) <= r2).any(axis=0)]
                    labels[new] = cluster
                    found.append(new)
            frontier = np.concatenate(found) if found else frontier[:0]
            frontier = frontier[core[frontier]]
        cluster += 1
    return labels[where]


def _core_distances(x: np.ndarray, k: int) -> np.ndarray:
    """Distance to the k-th nearest point, the point itself counted (scikit-learn's `kneighbors(x, k)`).
    Per leaf: the k-th distance among the points of the nearest boxes (at least FIRST of them) bounds
    each row's; a row whose bound reaches into other boxes is searched again over all it reaches."""
    t = _Leaves(x)
    out = np.empty(x.shape[0])
    sizes = np.diff(t.start)
    for leaf in t.leaves():
        by_gap = np.argsort(t.box_gaps(leaf), kind="stable")
        first = by_gap[:int(np.searchsorted(np.cumsum(sizes[by_gap]), max(k, _Leaves.FIRST))) + 1]
        near = np.partition(t.sq_dists(leaf, t.points(first)), k - 1, axis=1)[:, k - 1]
        reached = t.point_gaps(leaf) < near[:, None]  # a box at the bound cannot lower it
        reached[:, first] = False
        again = np.flatnonzero(reached.any(axis=1))
        if again.size:
            boxes = np.union1d(first, np.flatnonzero(reached[again].any(axis=0)))
            rows = t.x[t.start[leaf] + again]
            near[again] = np.partition(_sq_dists(rows, t.cols[:, t.points(boxes)]), k - 1, axis=1)[:, k - 1]
        out[t.order[t.rows(leaf)]] = near
    return np.sqrt(out)


def _prim(x: np.ndarray, core: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum spanning tree of the mutual reachability distances max(core_i, core_j, d_ij), in the
    order and orientation scikit-learn's `mst_from_data_matrix` gives it: from point 0, each step adds
    the lowest-index point of least reachability to the tree, by the edge from the first tree point
    that reached it at that distance.  Distances are one row per step; points already in the tree are
    dropped from the working arrays every so often (order kept, so ties still go to the lowest index)."""
    n = x.shape[0]
    src, dst, weight = np.empty(n - 1, dtype=np.int64), np.empty(n - 1, dtype=np.int64), np.empty(n - 1)
    live = np.arange(n)  # the points the working arrays hold, in index order
    cols, live_core = np.ascontiguousarray(x.T), core.copy()
    reach = np.full(n, np.inf)  # each point's least reachability from the tree so far
    via = np.zeros(n, dtype=np.int64)  # the tree point giving it
    in_tree = np.zeros(n, dtype=bool)
    diff, better = np.empty_like(cols), np.empty(n, dtype=bool)
    pos, done = 0, 0  # position of the newest tree point in the working arrays; tree points held there
    for i in range(n - 1):
        node = live[pos]
        in_tree[pos], done = True, done + 1
        live_core[pos] = np.inf  # a tree point's reachability never improves, so it is never picked
        reach[pos] = np.inf
        if done * 4 > live.size:  # compact: keep the points outside the tree
            keep = ~in_tree
            live, cols, live_core = live[keep], cols[:, keep], live_core[keep]
            reach, via, in_tree, done = reach[keep], via[keep], in_tree[keep], 0
            diff, better = diff[:, :live.size], better[:live.size]
        np.subtract(cols, x[node][:, None], out=diff)
        diff *= diff
        d = diff[0]
        for k in range(1, diff.shape[0]):  # summed in column order, as scikit-learn sums
            d += diff[k]
        np.sqrt(d, out=d)
        np.maximum(d, live_core, out=d)
        np.maximum(d, core[node], out=d)
        np.less(d, reach, out=better)
        np.copyto(reach, d, where=better)
        np.copyto(via, node, where=better)
        pos = int(np.argmin(reach))
        src[i], dst[i], weight[i] = via[pos], live[pos], reach[pos]
    return src, dst, weight


def _single_linkage(n: int, src: np.ndarray, dst: np.ndarray, weight: np.ndarray):
    """The merge tree (scipy's linkage layout: merge i makes node n + i) of the spanning tree's edges
    sorted by weight with numpy's default argsort, as scikit-learn sorts them (ties in its order)."""
    order = np.argsort(weight)
    parent = np.arange(2 * n - 1)  # union-find; merge i's node is the new root of both sides
    left, right = np.empty(n - 1, dtype=np.int64), np.empty(n - 1, dtype=np.int64)
    size = np.ones(2 * n - 1, dtype=np.int64)

    def root(a: int) -> int:
        top = a
        while parent[top] != top:
            top = parent[top]
        while parent[a] != top:
            parent[a], a = top, parent[a]
        return top

    for i, e in enumerate(order.tolist()):
        a, b = root(int(src[e])), root(int(dst[e]))
        left[i], right[i] = a, b
        size[n + i] = size[a] + size[b]
        parent[a] = parent[b] = n + i
    return left, right, weight[order], size


def _condense(n: int, left: np.ndarray, right: np.ndarray, dist: np.ndarray, size: np.ndarray,
              min_cluster_size: int):
    """The condensed tree as rows (parent cluster, child, lambda, child size), in scikit-learn's order:
    merges walked breadth-first from the root; a split into two sides of min_cluster_size points or
    more makes two new clusters (numbered from n + 1 in that order, the root being n); a smaller side's
    points leave their cluster at lambda = 1 / distance (listed breadth-first); a larger side goes on
    as the cluster itself."""
    lefts, rights = left.tolist(), right.tolist()

    def walk(top: int) -> list[int]:  # breadth-first nodes under `top`
        out, queue = [], [top]
        while queue:
            out += queue
            queue = [c for m in queue if m >= n for c in (lefts[m - n], rights[m - n])]
        return out

    label = {2 * n - 2: n}
    next_label = n + 1
    rows: list[tuple[int, int, float, int]] = []
    skip = np.zeros(2 * n - 1, dtype=bool)
    for node in walk(2 * n - 2):
        if node < n or skip[node]:
            continue
        a, b, d = lefts[node - n], rights[node - n], float(dist[node - n])
        lam = 1.0 / d if d > 0.0 else np.inf
        here = label[node]
        big = [int(size[a]) >= min_cluster_size, int(size[b]) >= min_cluster_size]
        for side, is_big in zip((a, b), big):
            if is_big and all(big):
                label[side] = next_label
                next_label += 1
                rows.append((here, label[side], lam, int(size[side])))
            elif is_big:
                label[side] = here
            else:
                for sub in walk(side):
                    if sub < n:
                        rows.append((here, sub, lam, 1))
                    skip[sub] = True
    return rows


def _select(rows, n: int, cluster_selection_epsilon: float) -> np.ndarray:
    """Excess-of-mass selection (the root excluded), then scikit-learn's epsilon merging, then each
    point labelled by its selected ancestor (numbered by cluster id) or noise."""
    parent = np.array([r[0] for r in rows], dtype=np.int64)
    child = np.array([r[1] for r in rows], dtype=np.int64)
    lam = np.array([r[2] for r in rows])
    csize = np.array([r[3] for r in rows], dtype=np.int64)
    top = int(parent.max())
    birth = np.full(max(top, int(child.max())) + 1, np.nan)
    birth[child] = lam
    birth[n] = 0.0
    # stability: sum of (lambda - birth) * size over each cluster's rows, added in row order
    stability = np.bincount(parent - n, weights=(lam - birth[parent]) * csize, minlength=top - n + 1).tolist()
    is_cluster = {c: True for c in range(top, n, -1)}  # children before parents (ids grow downwards)
    kids: dict[int, list[int]] = {}
    for p, c, s in zip(parent.tolist(), child.tolist(), csize.tolist()):
        if s > 1:
            kids.setdefault(p, []).append(c)

    def below(c: int) -> list[int]:
        out, queue = [], [c]
        while queue:
            out += queue
            queue = [k for q in queue for k in kids.get(q, [])]
        return out[1:]

    for c in is_cluster:
        sub = float(np.sum([stability[k - n] for k in kids.get(c, [])]))
        if sub > stability[c - n]:
            is_cluster[c] = False
            stability[c - n] = sub
        else:
            for k in below(c):
                is_cluster[k] = False
    selected = {c for c, keep in is_cluster.items() if keep}
    if cluster_selection_epsilon != 0.0 and kids:
        selected = _epsilon_merge([c for c, keep in is_cluster.items() if keep], parent, child, lam, kids, n,
                                  cluster_selection_epsilon, below)
    number = {c: i for i, c in enumerate(sorted(selected))}
    up = dict(zip(child.tolist(), parent.tolist()))
    labels = np.full(n, -1, dtype=np.int64)
    for p in range(n):
        c = up[p]
        while c != n and c not in number:
            c = up[c]
        if c != n:
            labels[p] = number[c]
    return labels


def _epsilon_merge(eom: list[int], parent, child, lam, kids, n: int, epsilon: float, below) -> set[int]:
    """scikit-learn's `epsilon_search`: a selected cluster born below distance epsilon is replaced by its
    lowest ancestor born above it (or by the root's child it descends from)."""
    born = {c: float(1 / lam[child == c][0]) for c in child[child > n].tolist()}  # 1 / lambda, as there
    up = {c: int(p) for p, c in zip(parent.tolist(), child.tolist()) if c > n}
    chosen, done = [], []
    for leaf in set(eom):  # iterated as scikit-learn iterates the same set
        if born[leaf] < epsilon:
            if leaf not in done:
                c = leaf
                while up[c] != n and born[up[c]] <= epsilon:
                    c = up[c]
                pick = c if up[c] == n else up[c]
                chosen.append(pick)
                done += below(pick)
        else:
            chosen.append(leaf)
    return set(chosen)


def hdbscan(x: np.ndarray, min_cluster_size: int, min_samples: int | None = None,
            cluster_selection_epsilon: float = 0.0) -> np.ndarray:
    """`sklearn.cluster.HDBSCAN(min_cluster_size, min_samples, cluster_selection_epsilon,
    copy=True).fit_predict(x)` (its other parameters at their defaults): labels, -1 noise.  Fewer than
    2 rows are noise (scikit-learn refuses them); min_samples (default min_cluster_size) above the row
    count is refused as scikit-learn refuses it."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    n = x.shape[0]
    if n < 2:
        return np.full(n, -1, dtype=np.int64)
    k = min_cluster_size if min_samples is None else min_samples
    if k > n:
        raise ValueError(f"min_samples ({k}) must be at most the number of samples in X ({n})")
    src, dst, weight = _prim(x, _core_distances(x, k))
    left, right, dist, size = _single_linkage(n, src, dst, weight)
    rows = _condense(n, left, right, dist, size, min_cluster_size)
    return _select(rows, n, float(cluster_selection_epsilon))
