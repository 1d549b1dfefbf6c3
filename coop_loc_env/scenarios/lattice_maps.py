"""Symmetric corridor lattices, drawn from a seed (the maps of ``active_lattice``).

A lattice has ``size x size`` junctions ``PITCH`` m apart joined by ``CORRIDOR`` m wide
corridors, centred in a square world of at least ``FRAME`` m (the space outside the
corridors is solid). The map is built on a raster of ``RES`` m cells
(``PITCH / RES = 8`` cells per pitch) and handed to the env as solid rectangles:

* **Symmetry.** Which corridors exist and which dead-end spurs leave the outer
  junctions is drawn orbit by orbit under the turns of order ``symmetry`` (2: half
  turns; 4: quarter turns) about the centre: a choice made for one sector is
  rotated onto the others, so the lattice looks the same after those turns.
  Corridors are removed only while every junction stays reachable.
* **The bay** (one per map): a plaza, the solid block between four neighbouring
  junctions opened with the corridors around it (``PLAZA`` m square), at one place
  only: it breaks the symmetry. A sonar robot sees it from the corridors next to it.
* **Decoys** (``decoys``, 4-fold maps only): the same plaza at a place *and* at its
  half-turn copy, which leaves the map 2-fold symmetric: seeing one halves the
  hypotheses, where the bay picks one.

:func:`lattice_map` is cached per parameters (maps are small and drawn often).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from coop_loc_env.config import Obstacle

PITCH = 5.0  # m between neighbouring junctions
CORRIDOR = 2.5  # m, corridor width
RES = 0.625  # m, raster cell: 8 per pitch, 4 per corridor width
FRAME = 40.0  # m: smallest world edge, so lattices up to 7 x 7 share one frame
PLAZA = PITCH + CORRIDOR  # m, edge of the open square of the bay and of each decoy
SPUR = 2.5  # m, length of a dead-end spur beyond an outer junction
REMOVE_P = 0.35  # chance an orbit of corridors is removed (while all junctions stay linked)
SPUR_P = 0.4  # chance an orbit of outer junctions grows a spur
SYMMETRIES = (2, 4)
STARTS = ("together", "scattered")

_C = int(round(CORRIDOR / RES))  # 4 cells
_P = int(round(PITCH / RES))  # 8 cells
_S = int(round(SPUR / RES))  # 4 cells


@dataclass(frozen=True)
class LatticeMap:
    """One drawn lattice.

    Attributes:
        world: world edge (m; the world is square).
        free: ``(n, n)`` raster, True where robots can drive; cell ``(iy, ix)`` covers
            ``[ix, ix + 1) * RES`` in x and the same in y.
        obstacles: the solid rectangles covering every other cell.
        junctions: ``(size * size, 2)`` junction centres (m).
        bay: ``(2,)`` centre of the bay's plaza (m).
        decoys: ``(k, 2)`` centres of the decoy plazas (both copies of each).
        symmetry: the order of the turns the lattice (without the features) is symmetric under.
    """

    world: float
    free: np.ndarray
    obstacles: tuple[Obstacle, ...]
    junctions: np.ndarray
    bay: np.ndarray
    decoys: np.ndarray
    symmetry: int

    def to_world(self, cells: np.ndarray) -> np.ndarray:
        """Centres (m) of raster cells ``(k, 2)`` given as ``(iy, ix)``."""
        cells = np.asarray(cells, dtype=float).reshape(-1, 2)
        return (cells[:, ::-1] + 0.5) * RES


def check_params(lattice_size: int, symmetry: int, decoys: int, map_seed: int | None,
                 start: str) -> None:
    """``ValueError`` naming the first bad lattice parameter."""
    if isinstance(lattice_size, bool) or not isinstance(lattice_size, int) or lattice_size < 3:
        raise ValueError(f"lattice_size must be an integer >= 3, got {lattice_size!r}")
    if isinstance(symmetry, bool) or symmetry not in SYMMETRIES:
        raise ValueError(f"symmetry must be one of {SYMMETRIES}, got {symmetry!r}")
    if isinstance(decoys, bool) or not isinstance(decoys, int) or decoys < 0:
        raise ValueError(f"decoys must be an integer >= 0, got {decoys!r}")
    if decoys and symmetry != 4:
        raise ValueError(f"decoys need symmetry=4 (a decoy keeps half of a 4-fold symmetry), "
                         f"got decoys={decoys} with symmetry={symmetry}")
    if map_seed is not None and (isinstance(map_seed, bool) or not isinstance(map_seed, int)
                                 or map_seed < 0):
        raise ValueError(f"map_seed must be None or an integer >= 0, got {map_seed!r}")
    if start not in STARTS:
        raise ValueError(f"start must be one of {STARTS}, got {start!r}")


def world_edge(lattice_size: int) -> float:
    """The world edge (m) of a ``lattice_size`` lattice: ``FRAME``, or more for large ones
    (a whole number of raster cells, even, so the centre lies on a cell corner)."""
    need = (lattice_size - 1) * PITCH + CORRIDOR + 2 * (SPUR + RES)  # one solid cell round
    cells = int(np.ceil(max(FRAME, need) / RES))
    return (cells + cells % 2) * RES


def _rot(node: tuple[int, int], k: int, n: int) -> tuple[int, int]:
    """Junction ``(i, j)`` (column, row) turned ``k`` quarter turns counter-clockwise."""
    i, j = node
    for _ in range(k % 4):
        i, j = n - 1 - j, i
    return i, j


def _orbits(items, turn, steps: tuple[int, ...]) -> list[tuple]:
    """The orbits of ``items`` under ``turn(item, k)`` for ``k`` in ``steps``."""
    seen, out = set(), []
    for it in items:
        if it in seen:
            continue
        orbit = tuple(dict.fromkeys(turn(it, k) for k in steps))
        seen.update(orbit)
        out.append(orbit)
    return out


def _edge(a, b):
    return (a, b) if a <= b else (b, a)


def _connected(n: int, edges: set) -> bool:
    adj: dict = {}
    for a, b in edges:
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, []).append(a)
    start = (0, 0)
    seen, todo = {start}, [start]
    while todo:
        for m in adj.get(todo.pop(), ()):
            if m not in seen:
                seen.add(m)
                todo.append(m)
    return len(seen) == n * n


def _rectangles(solid: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Cover the True cells of ``solid`` with disjoint rectangles ``(iy0, ix0, iy1, ix1)``
    (exclusive ends): maximal row runs, merged down while the run below matches."""
    todo = solid.copy()
    out = []
    ny, nx = todo.shape
    for iy in range(ny):
        ix = 0
        while ix < nx:
            if not todo[iy, ix]:
                ix += 1
                continue
            end = ix
            while end < nx and todo[iy, end]:
                end += 1
            bottom = iy + 1
            while bottom < ny and todo[bottom, ix:end].all():
                bottom += 1
            todo[iy:bottom, ix:end] = False
            out.append((iy, ix, bottom, end))
            ix = end
    return out


@functools.lru_cache(maxsize=256)
def lattice_map(lattice_size: int = 5, symmetry: int = 4, decoys: int = 1, seed: int = 0
                ) -> LatticeMap:
    """The lattice drawn from ``seed`` (module doc); the same arguments give the same map."""
    check_params(lattice_size, symmetry, decoys, seed, "together")
    n = lattice_size
    rng = np.random.default_rng([seed, n, symmetry, decoys])
    steps = (0, 2) if symmetry == 2 else (0, 1, 2, 3)
    edges = {_edge((i, j), (i + 1, j)) for i in range(n - 1) for j in range(n)}
    edges |= {_edge((i, j), (i, j + 1)) for i in range(n) for j in range(n - 1)}
    edge_orbits = _orbits(sorted(edges), lambda e, k: _edge(_rot(e[0], k, n), _rot(e[1], k, n)),
                          steps)
    for idx in rng.permutation(len(edge_orbits)):
        orbit = edge_orbits[idx]
        if rng.random() < REMOVE_P and _connected(n, edges - set(orbit)):
            edges -= set(orbit)
    # spurs: an outer junction and its outward direction (dx, dy)
    outward = [((i, j), d) for i in range(n) for j in range(n)
               for d in ((-1, 0), (1, 0), (0, -1), (0, 1))
               if not (0 <= i + d[0] < n and 0 <= j + d[1] < n)]

    def turn_spur(s, k):
        (node, d) = s
        for _ in range(k % 4):
            d = (-d[1], d[0])
        return (_rot(node, k, n), d)

    spurs = set()
    for orbit in _orbits(outward, turn_spur, steps):
        if rng.random() < SPUR_P:
            spurs |= set(orbit)

    world = world_edge(n)
    cells = int(round(world / RES))
    org = cells // 2 - (n - 1) * _P // 2  # raster index of junction (0, 0)'s centre line
    free = np.zeros((cells, cells), dtype=bool)
    half = _C // 2
    for i in range(n):
        for j in range(n):
            cx, cy = org + i * _P, org + j * _P
            free[cy - half:cy + half, cx - half:cx + half] = True
    for (i0, j0), (i1, j1) in edges:
        xa, xb = sorted((org + i0 * _P, org + i1 * _P))
        ya, yb = sorted((org + j0 * _P, org + j1 * _P))
        free[ya - half:yb + half, xa - half:xb + half] = True
    for (i, j), (dx, dy) in spurs:
        cx, cy = org + i * _P, org + j * _P
        if dx:
            xa = cx + half if dx > 0 else cx - half - _S
            free[cy - half:cy + half, xa:xa + _S] = True
        else:
            ya = cy + half if dy > 0 else cy - half - _S
            free[ya:ya + _S, cx - half:cx + half] = True

    # features: plazas, each the block whose lower-left junction is (i, j), the bay on an
    # orbit of blocks of its own, each decoy on another, with its half-turn copy
    def turn_block(b, k):
        (i, j) = b
        for _ in range(k % 4):
            i, j = n - 2 - j, i
        return (i, j)

    blocks = [(i, j) for i in range(n - 1) for j in range(n - 1)]
    block_orbits = [o for o in _orbits(blocks, turn_block, (0, 1, 2, 3)) if len(o) == 4]
    picks = rng.permutation(len(block_orbits))[: 1 + decoys]
    if len(picks) < 1 + decoys:
        raise ValueError(f"a {n} x {n} lattice has room for {len(block_orbits) - 1} decoys, "
                         f"got decoys={decoys}")
    bay_block = block_orbits[picks[0]][rng.integers(4)]
    decoy_blocks = []
    for p in picks[1:]:
        first = block_orbits[p][rng.integers(4)]
        decoy_blocks += [first, turn_block(first, 2)]

    def plaza(block) -> tuple[slice, slice]:
        i, j = block
        return (slice(org + j * _P - half, org + (j + 1) * _P + half),
                slice(org + i * _P - half, org + (i + 1) * _P + half))

    def centre(block) -> np.ndarray:
        ys, xs = plaza(block)
        return np.array([(xs.start + xs.stop) / 2, (ys.start + ys.stop) / 2]) * RES

    for block in [bay_block, *decoy_blocks]:
        free[plaza(block)] = True
    obstacles = tuple(
        Obstacle("wall", "polygon", vertices=((x0 * RES, y0 * RES), (x1 * RES, y0 * RES),
                                              (x1 * RES, y1 * RES), (x0 * RES, y1 * RES)))
        for y0, x0, y1, x1 in _rectangles(~free)
    )
    junctions = np.array([((org + i * _P) * RES, (org + j * _P) * RES)
                          for j in range(n) for i in range(n)])
    free.setflags(write=False)
    return LatticeMap(world=world, free=free, obstacles=obstacles, junctions=junctions,
                      bay=centre(bay_block),
                      decoys=np.array([centre(b) for b in decoy_blocks]).reshape(-1, 2),
                      symmetry=symmetry)


def start_poses(lmap: LatticeMap, n_robots: int, start: str, radius: float,
                rng: np.random.Generator, together_m: float = 3.0) -> np.ndarray:
    """``(n_robots, 3)`` start poses on the corridors' middle cells: ``"together"`` within
    ``together_m`` m of a drawn point, ``"scattered"`` anywhere; headings uniform."""
    free = lmap.free
    # cells whose whole 3 x 3 neighbourhood is free: at least one cell (0.625 m) of
    # clearance around a robot centre at the cell's centre
    inner = free.copy()
    inner[1:-1, 1:-1] &= free[:-2, 1:-1] & free[2:, 1:-1] & free[1:-1, :-2] & free[1:-1, 2:]
    inner[1:-1, 1:-1] &= free[:-2, :-2] & free[2:, 2:] & free[:-2, 2:] & free[2:, :-2]
    pts = lmap.to_world(np.argwhere(inner))
    gap = 2 * radius + 0.3
    for _ in range(100):
        if start == "together":
            c = pts[rng.integers(len(pts))]
            near = pts[np.hypot(*(pts - c).T) <= together_m]
        else:
            near = pts
        chosen: list[np.ndarray] = []
        for k in rng.permutation(len(near)):
            p = near[k]
            if all(np.hypot(*(p - q)) > gap for q in chosen):
                chosen.append(p)
                if len(chosen) == n_robots:
                    break
        if len(chosen) == n_robots:
            xy = np.array(chosen)
            if start == "together":  # within together_m of each other's centre
                xy = xy[np.argsort(np.hypot(*(xy - c).T))]
            return np.column_stack([xy, rng.uniform(-np.pi, np.pi, n_robots)])
    raise ValueError(f"cannot place {n_robots} robots {start} on this lattice")
