"""
The constraint graph: connected components, spanning forests and the loops they leave.

Conventions
-----------
The ``n`` bodies are the nodes ``0 .. n − 1`` and the fixed world is node
``n``. A constraint row (or a whole constraint, a *joint*) is an edge between
its bodies ``a[r]`` (``0 <= a[r] < n``) and ``b[r]`` (``0 <= b[r] <= n``);
``b[r] == a[r]`` is a row on one body, which joins nothing. The world does not
move, so it couples no bodies: a row to the world joins a body to no other.

What is asked of the graph, when the constraint set changes (never per step,
plain Python):

* which bodies move together (:func:`component_labels`): the compiled step takes
  each connected component on its own, with the sub-steps its own motion needs;
* whether joints close a loop, and which edges close it (:func:`closing_edges`:
  an edge closes a loop when the edges before it already connect its ends,
  Kruskal's test; the edges that close none form a spanning forest), through
  the world too (:func:`closes_loop`);
* the elimination order of a forest for the linear-time tree solve of
  :mod:`.kernels.tree_solve` (:func:`tree_structure`, Baraff 1996), and the
  split of a graph with loops into a spanning forest and the rows that close
  its loops for :mod:`.kernels.loop_solve` (:func:`loop_structure`).

One union-find (:class:`DisjointSets`) answers all of them. The compiled
solves take the arrays of the structures built here.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np


class DisjointSets:
    """
    Union-find over the nodes ``0 .. n − 1`` (path halving); a set is named by its least node.

    Parameters
    ----------
    n : int
        Number of nodes.

    """

    def __init__(self, n: int) -> None:
        self.parent = list(range(int(n)))

    def find(self, i: int) -> int:
        """Return the least node of the set of node ``i``."""
        parent = self.parent
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def union(self, i: int, j: int) -> bool:
        """Join the sets of nodes ``i`` and ``j``; False if they were one set already."""
        ri, rj = self.find(i), self.find(j)
        if ri == rj:
            return False
        if ri < rj:
            self.parent[rj] = ri
        else:
            self.parent[ri] = rj
        return True


def component_labels(a, b, n_bodies: int) -> np.ndarray:
    """
    Label each body with the least body of its connected component.

    Parameters
    ----------
    a, b : array_like of int, shape (m,)
        Bodies of each row (``b == n_bodies``: the world, which joins nothing).
    n_bodies : int
        Number of bodies ``n``.

    Returns
    -------
    ndarray of int64, shape (n,)
        The label of each body; a body in no row is a component of its own.

    """
    n = int(n_bodies)
    sets = DisjointSets(n)
    for i, j in zip(np.asarray(a).tolist(), np.asarray(b).tolist()):
        if j < n:
            sets.union(i, j)
    return np.array([sets.find(i) for i in range(n)], dtype=np.int64)


def closing_edges(a, b, n_nodes: int) -> np.ndarray:
    """
    Tell, per edge, whether it closes a loop of the edges before it.

    An edge whose ends the earlier edges already connect closes a loop (an edge
    given twice closes a loop of two, one from a node to itself a loop of one);
    the edges that close none form a spanning forest of the graph.

    Parameters
    ----------
    a, b : array_like of int, shape (k,)
        The ends of each edge, ``0 <= a, b < n_nodes``, in the order taken.
    n_nodes : int
        Number of nodes.

    Returns
    -------
    ndarray of bool, shape (k,)

    """
    sets = DisjointSets(n_nodes)
    return np.array([not sets.union(i, j)
                     for i, j in zip(np.asarray(a).tolist(), np.asarray(b).tolist())],
                    dtype=bool)


def closes_loop(a, b, n_bodies: int) -> bool:
    """
    Tell whether joints close a loop, through the world too.

    Parameters
    ----------
    a, b : array_like of int, shape (k,)
        The bodies of each joint (``b == n_bodies``: the world). A joint given
        twice closes a loop of two (its rows are redundant too); a joint on one
        body (``a == b``) joins nothing.
    n_bodies : int
        Number of bodies ``n``.

    Returns
    -------
    bool

    """
    a = np.asarray(a, dtype=np.int64).ravel()
    b = np.asarray(b, dtype=np.int64).ravel()
    keep = a != b
    return bool(closing_edges(a[keep], b[keep], int(n_bodies) + 1).any())


class TreeStructure(NamedTuple):
    """
    Elimination structure of a constraint forest (built by :func:`tree_structure`).

    Groups are numbered in elimination order (see "Graph" in :mod:`.kernels.tree_solve`).

    Attributes
    ----------
    group_ptr : ndarray of int64, shape (n_groups + 1,)
        CSR pointer: the rows of group ``x`` are
        ``group_rows[group_ptr[x]:group_ptr[x + 1]]``.
    group_rows : ndarray of int64, shape (m,)
        Row indices grouped by group (a permutation of ``0 .. m − 1``).
    group_child : ndarray of int64, shape (n_groups,)
        Child body of a group between two bodies (farther from the root),
        ``-1`` for the group of a body's rows to the world (or to itself).
    group_parent : ndarray of int64, shape (n_groups,)
        Parent body (nearer the root), or the only body of a world group.
    row_side : ndarray of int64, shape (m,)
        Where the block of row ``r`` on its group's parent body is: 0 in
        ``Ga``/``Ha`` (the block on the child body is then in ``Gb``/``Hb``),
        1 in ``Gb``/``Hb`` (child block in ``Ga``/``Ha``), 2 in the sum
        ``Ga + Gb`` (``a[r] == b[r]``, no child).
    row_group : ndarray of int64, shape (m,)
        Group of each row.
    group_body_parent : ndarray of int64, shape (n_bodies,)
        For information: the group linking each body to its parent body
        (``-1`` for roots and bodies in no group).
    block_size : int
        ``K``: the largest group (at least 1); pivot blocks are padded to (K, K).
    n_bodies : int
        Number of bodies ``n``.

    """

    group_ptr: np.ndarray
    group_rows: np.ndarray
    group_child: np.ndarray
    group_parent: np.ndarray
    row_side: np.ndarray
    row_group: np.ndarray
    group_body_parent: np.ndarray
    block_size: int
    n_bodies: int

    @property
    def n_groups(self) -> int:
        """Return the number of groups."""
        return int(self.group_child.shape[0])

    @property
    def arrays(self) -> tuple:
        """``(group_ptr, group_rows, group_child, group_parent, row_side)``: kernel arguments."""
        return self.group_ptr, self.group_rows, self.group_child, self.group_parent, self.row_side


def tree_structure(a, b, n_bodies: int) -> Optional[TreeStructure]:
    """
    Group the rows, build Baraff's body/group graph and order the groups leaves first.

    Rows acting on the same unordered pair of distinct bodies form a group; the
    rows of a body to the world (or to itself) form one group of that body
    (see "Graph" in :mod:`.kernels.tree_solve`).

    Parameters
    ----------
    a : array_like of int, shape (m,)
        First body of each row, ``0 <= a[r] < n_bodies``.
    b : array_like of int, shape (m,)
        Second body of each row, ``0 <= b[r] <= n_bodies`` (``n_bodies``: the world).
    n_bodies : int
        Number of bodies ``n``.

    Returns
    -------
    TreeStructure or None
        The structure, or ``None`` when the graph has a cycle (a closed loop of
        groups between bodies): see :func:`loop_structure`.

    Raises
    ------
    ValueError
        If ``a`` and ``b`` differ in shape or hold out-of-range bodies.

    """
    a = np.asarray(a, dtype=np.int64).ravel()
    b = np.asarray(b, dtype=np.int64).ravel()
    n = int(n_bodies)
    if a.shape != b.shape:
        raise ValueError(f'a and b must have the same length, got {a.size} and {b.size}')
    if a.size and (a.min() < 0 or a.max() >= n or b.min() < 0 or b.max() > n):
        raise ValueError('body indices out of range: need 0 <= a < n_bodies, 0 <= b <= n_bodies')
    m = a.size
    world_rows = [[] for _ in range(n)]   # rows to the world (or acting on one body)
    group_of_pair = {}
    pair_rows = []
    pair_bodies = []
    for r in range(m):
        ar, br = int(a[r]), int(b[r])
        if br == n or br == ar:
            world_rows[ar].append(r)
            continue
        key = (min(ar, br), max(ar, br))
        g = group_of_pair.get(key)
        if g is None:
            g = group_of_pair[key] = len(pair_rows)
            pair_rows.append([])
            pair_bodies.append(key)
        pair_rows[g].append(r)
    # A cycle of the bipartite body/group graph is a cycle of the graph of bodies with one edge
    # per pair group (the pairs are distinct).
    ends = np.array(pair_bodies, dtype=np.int64).reshape(-1, 2)
    if closing_edges(ends[:, 0], ends[:, 1], n).any():
        return None
    adjacent = [[] for _ in range(n)]   # (pair group, other body) per body
    for g, (i, j) in enumerate(pair_bodies):
        adjacent[i].append((g, j))
        adjacent[j].append((g, i))
    # Breadth-first from a root body per tree; reversed, the visit order has children first.
    up_group = np.full(n, -1, dtype=np.int64)   # pair group to the parent body
    up_body = np.full(n, -1, dtype=np.int64)
    visited = np.zeros(n, dtype=bool)
    bfs = []
    for root in range(n):
        if visited[root] or not (world_rows[root] or adjacent[root]):
            continue
        visited[root] = True
        head = len(bfs)
        bfs.append(root)
        while head < len(bfs):
            body = bfs[head]
            head += 1
            for g, other in adjacent[body]:
                if not visited[other]:
                    visited[other] = True
                    up_group[other] = g
                    up_body[other] = body
                    bfs.append(other)
    # Per body, leaves first: its world group, then the group to its parent body.
    ptr, rows, child, parent, side = [0], [], [], [], np.zeros(m, dtype=np.int64)
    group_body_parent = np.full(n, -1, dtype=np.int64)
    for body in reversed(bfs):
        if world_rows[body]:
            for r in world_rows[body]:
                side[r] = 2 if a[r] == b[r] else 0
            rows.extend(world_rows[body])
            ptr.append(len(rows))
            child.append(-1)
            parent.append(body)
        if up_group[body] >= 0:
            own = pair_rows[up_group[body]]
            for r in own:
                side[r] = 0 if a[r] == up_body[body] else 1
            rows.extend(own)
            ptr.append(len(rows))
            group_body_parent[body] = len(child)
            child.append(body)
            parent.append(int(up_body[body]))
    group_ptr = np.array(ptr, dtype=np.int64)
    group_rows = np.array(rows, dtype=np.int64)
    row_group = np.empty(m, dtype=np.int64)
    row_group[group_rows] = np.repeat(np.arange(len(child), dtype=np.int64), np.diff(group_ptr))
    block = int(np.diff(group_ptr).max()) if len(child) else 1
    return TreeStructure(group_ptr, group_rows, np.array(child, dtype=np.int64),
                         np.array(parent, dtype=np.int64), side, row_group, group_body_parent,
                         block, n)


class LoopStructure(NamedTuple):
    """
    A spanning forest of the constraint graph and the rows that close its loops.

    Attributes
    ----------
    tree : TreeStructure
        The tree solve's structure of the forest's rows, in the numbering of
        all ``m`` rows (the closure rows are in no group).
    closure : ndarray of int64, shape (c,)
        The rows of the groups left out of the forest, ascending.

    """

    tree: TreeStructure
    closure: np.ndarray


def loop_structure(a, b, n_bodies: int, through_world: bool = False,
                   forced=()) -> Optional[LoopStructure]:
    """
    Split the rows into a spanning forest and loop-closing rows (see :mod:`.kernels.loop_solve`).

    Groups (the rows between one pair of bodies) are taken in the order of
    their first row; a group whose two bodies are already connected closes a
    loop (:func:`closing_edges`). Returns None when there is no loop (use
    :func:`tree_structure` alone). The world couples no rows, so a loop through
    it leaves the system tree-structured; with ``through_world`` it is a node
    all the same, and a second joint to the world closes a loop: the redundant
    rows of such a loop (a four-bar's three) then meet the closure block's
    truncated SVD instead of the tree solve's Tikhonov term. The rows in
    ``forced`` are closure rows whatever the graph (rows that couple more than
    the two bodies they are listed on: a mimic joint's), and form no edge.
    """
    a = np.asarray(a, dtype=np.int64).ravel()
    b = np.asarray(b, dtype=np.int64).ravel()
    n = int(n_bodies)
    forced = set(np.asarray(forced, dtype=np.int64).ravel().tolist())
    pairs: dict = {}   # pair -> its index in first-row order
    joins = [(b[r] != n or through_world) and b[r] != a[r] and r not in forced
             for r in range(a.size)]
    for ar, br, j in zip(a.tolist(), b.tolist(), joins):
        if j:
            pairs.setdefault((min(ar, br), max(ar, br)), len(pairs))
    ends = np.array(list(pairs), dtype=np.int64).reshape(-1, 2)
    closing = closing_edges(ends[:, 0], ends[:, 1], n + 1)
    closure = np.array([r for r in range(a.size)
                        if r in forced
                        or (joins[r] and closing[pairs[(min(a[r], b[r]), max(a[r], b[r]))]])],
                       dtype=np.int64)
    if not closure.size:
        return None
    keep = np.setdiff1d(np.arange(a.size), closure)
    sub = tree_structure(a[keep], b[keep], n)
    side = np.zeros(a.size, dtype=np.int64)
    side[keep] = sub.row_side
    group = np.full(a.size, -1, dtype=np.int64)
    group[keep] = sub.row_group
    tree = sub._replace(group_rows=keep[sub.group_rows], row_side=side, row_group=group)
    return LoopStructure(tree, closure)
