"""Distances between convex shapes, compiled: the geometry of clearance checks and collision
avoidance.

A shape is a convex *core* (a point, a segment, a box, a cylinder or the convex hull of a vertex
list) swept by a sphere of radius ``RADIUS`` (a sphere is a point core, a capsule a segment
core), rigid in the frame of a body. Shapes are packed as rows of a float array (columns below):
its body (``WORLD`` for an obstacle, 0 the carrier, ``i`` link ``i``), its kind, its radius, its
pose in the body frame (position relative to the body's CoM, rotation matrix row-major whose
columns are the shape's axes), its dimensions and its bounding radius about its position
(margin included). A posed shape has the same row with the pose in the frame where distances
are taken (:func:`pose_into`).

The distance between two cores is computed by the Gilbert-Johnson-Keerthi algorithm on their
support functions (Gilbert, Johnson and Keerthi 1988; the sub-simplex search by Voronoi regions
as in Ericson, *Real-Time Collision Detection*, 2005, ch. 5 and 9), the same method coal
(hpp-fcl) uses: exact for polytopes, segments and points (it ends when the support point adds
nothing, to a relative ``1e-12`` of the distance), and converging linearly on cylinders. The
shapes' distance is the cores' distance less both radii, so it is negative when the swept
spheres overlap. Cores that intersect have a negative distance of their own: minus their
penetration depth (how far apart they must move to touch), by the expanding polytope algorithm
(EPA) from GJK's last simplex, with their deepest points as witnesses; within ``EPA_TOLERANCE``
of the shapes' size (coal's depth to 1e-15 m for polytopes in the tests, where EPA ends on a true
face; within 5e-7 m with a cylinder). Two segments (spheres, capsules) that cross have no depth
of their own: ``-(r_a + r_b)``.
"""

from __future__ import annotations

import numpy as np

from engine.kernels.jit import kernel, unlinked

# Columns of a shape row.
BODY, KIND, RADIUS, POS, ROT, DIMS, BOUND = 0, 1, 2, 3, 6, 15, 18
SHAPE_WIDTH = 19
# Kinds of core.
POINT, SEGMENT, BOX, CYLINDER, HULL = 0, 1, 2, 3, 4
#: The body of an obstacle (fixed in the world).
WORLD = -1

MAX_ITERATIONS = 128
RELATIVE_TOLERANCE = 1e-12
TINY = 1e-300


@kernel
def support(shape, vertices, dx, dy, dz, out):
    """The point of the posed ``shape``'s core farthest along ``(dx, dy, dz)`` into ``out (3,)``
    (``vertices (V, 3)``: the hulls' vertices in their shapes' frames)."""
    kind = int(shape[KIND])
    cx = shape[POS]
    cy = shape[POS + 1]
    cz = shape[POS + 2]
    if kind == POINT:
        out[0] = cx
        out[1] = cy
        out[2] = cz
        return
    # the shape's axes: the columns of its rotation
    if kind == SEGMENT:
        ax = shape[ROT + 2]
        ay = shape[ROT + 5]
        az = shape[ROT + 8]
        h = shape[DIMS]
        if dx * ax + dy * ay + dz * az < 0.0:
            h = -h
        out[0] = cx + h * ax
        out[1] = cy + h * ay
        out[2] = cz + h * az
        return
    if kind == BOX:
        x = cx
        y = cy
        z = cz
        for i in range(3):
            ex = shape[ROT + i]
            ey = shape[ROT + 3 + i]
            ez = shape[ROT + 6 + i]
            half = shape[DIMS + i]
            if dx * ex + dy * ey + dz * ez < 0.0:
                half = -half
            x += half * ex
            y += half * ey
            z += half * ez
        out[0] = x
        out[1] = y
        out[2] = z
        return
    if kind == CYLINDER:
        ax = shape[ROT + 2]
        ay = shape[ROT + 5]
        az = shape[ROT + 8]
        along = dx * ax + dy * ay + dz * az
        # the radial part in the cylinder's own x and y axes: perpendicular to its axis exactly
        # (the direction less its axial part is, along the axis, rounding noise in any direction)
        lx = dx * shape[ROT] + dy * shape[ROT + 3] + dz * shape[ROT + 6]
        ly = dx * shape[ROT + 1] + dy * shape[ROT + 4] + dz * shape[ROT + 7]
        norm = np.sqrt(lx * lx + ly * ly)
        h = shape[DIMS + 1] if along >= 0.0 else -shape[DIMS + 1]
        x = cx + h * ax
        y = cy + h * ay
        z = cz + h * az
        if norm > 1e-12 * (abs(dx) + abs(dy) + abs(dz)):  # else the cap's centre: as far as any of it
            rc = shape[DIMS] / norm
            x += rc * (lx * shape[ROT] + ly * shape[ROT + 1])
            y += rc * (lx * shape[ROT + 3] + ly * shape[ROT + 4])
            z += rc * (lx * shape[ROT + 6] + ly * shape[ROT + 7])
        out[0] = x
        out[1] = y
        out[2] = z
        return
    # HULL: the best vertex along the direction in the shape's frame
    lx = shape[ROT] * dx + shape[ROT + 3] * dy + shape[ROT + 6] * dz
    ly = shape[ROT + 1] * dx + shape[ROT + 4] * dy + shape[ROT + 7] * dz
    lz = shape[ROT + 2] * dx + shape[ROT + 5] * dy + shape[ROT + 8] * dz
    first = int(shape[DIMS])
    count = int(shape[DIMS + 1])
    best = first
    best_dot = -np.inf
    for k in range(first, first + count):
        dot = vertices[k, 0] * lx + vertices[k, 1] * ly + vertices[k, 2] * lz
        if dot > best_dot:
            best_dot = dot
            best = k
    vx = vertices[best, 0]
    vy = vertices[best, 1]
    vz = vertices[best, 2]
    out[0] = cx + shape[ROT] * vx + shape[ROT + 1] * vy + shape[ROT + 2] * vz
    out[1] = cy + shape[ROT + 3] * vx + shape[ROT + 4] * vy + shape[ROT + 5] * vz
    out[2] = cz + shape[ROT + 6] * vx + shape[ROT + 7] * vy + shape[ROT + 8] * vz


#: EPA's polytope holds at most this many points (and twice as many faces); the depth found by
#: then stands (polytopes end sooner, curved cores converge linearly).
EPA_MAX_POINTS = 128
EPA_MAX_FACES = 2 * EPA_MAX_POINTS
#: EPA ends when the support point along the nearest face's normal lies within this fraction of
#: the polytope's size beyond that face: the depth found is then short of the true one by at most
#: that (polytopes end exactly; on cylinders the gain per step shrinks slowly, and rounding breaks
#: a polytope of many nearly coplanar faces before a tighter tolerance is met).
EPA_TOLERANCE = 1e-7


@kernel
def gjk_buffers():
    """Scratch of :func:`core_distance`: ``(W, A, B (4, 3) simplex points and their shapes'
    points, lam (4,) barycentric weights, tmp (8, 3), kept (3, 4, 3) and kept_lam (4,): the
    simplex of the last step; then EPA's (:func:`_penetration`) points (3, EPA_MAX_POINTS, 3):
    the polytope's and each shape's, faces (EPA_MAX_FACES, 7) int64: three points, 1 while on
    the polytope (0 gone), and across each edge the neighbour's ``3 face + edge``, planes
    (EPA_MAX_FACES, 4): unit outward normal and the origin's distance, and (3 EPA_MAX_FACES, 5)
    int64: the horizon's edges (two points and the neighbour across), the search's stack, and
    the faces gone)``."""
    return (
        np.empty((4, 3)),
        np.empty((4, 3)),
        np.empty((4, 3)),
        np.empty(4),
        np.empty((8, 3)),
        np.empty((3, 4, 3)),
        np.empty(4),
        np.empty((3, EPA_MAX_POINTS, 3)),
        np.empty((EPA_MAX_FACES, 7), dtype=np.int64),
        np.empty((EPA_MAX_FACES, 4)),
        np.empty((3 * EPA_MAX_FACES, 5), dtype=np.int64),
    )


@kernel
def _keep(W, A, B, lam, idx, count):
    """Keep the simplex points ``idx[:count]`` (in that order) with their weights."""
    for k in range(count):
        src = idx[k]
        if src != k:
            for r in range(3):
                W[k, r] = W[src, r]
                A[k, r] = A[src, r]
                B[k, r] = B[src, r]
            lam[k] = lam[src]
    return count


@kernel
def _segment(W, A, B, lam, i, j, idx):
    """The point of segment ``W[i] W[j]`` closest to the origin: weights into ``lam[i], lam[j]``
    and the points kept into ``idx``; returns how many."""
    ex = W[j, 0] - W[i, 0]
    ey = W[j, 1] - W[i, 1]
    ez = W[j, 2] - W[i, 2]
    ee = ex * ex + ey * ey + ez * ez
    t = -(W[i, 0] * ex + W[i, 1] * ey + W[i, 2] * ez)
    if t <= 0.0 or ee <= TINY:
        lam[i] = 1.0
        idx[0] = i
        return 1
    if t >= ee:
        lam[j] = 1.0
        idx[0] = j
        return 1
    t /= ee
    lam[i] = 1.0 - t
    lam[j] = t
    idx[0] = i
    idx[1] = j
    return 2


@kernel
def _triangle(W, A, B, lam, i, j, k, idx):
    """The point of triangle ``W[i] W[j] W[k]`` closest to the origin (Ericson 5.1.5, with the
    origin as the query point): weights into ``lam`` and the points kept into ``idx``."""
    abx = W[j, 0] - W[i, 0]
    aby = W[j, 1] - W[i, 1]
    abz = W[j, 2] - W[i, 2]
    acx = W[k, 0] - W[i, 0]
    acy = W[k, 1] - W[i, 1]
    acz = W[k, 2] - W[i, 2]
    apx = -W[i, 0]
    apy = -W[i, 1]
    apz = -W[i, 2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        lam[i] = 1.0
        idx[0] = i
        return 1
    bpx = -W[j, 0]
    bpy = -W[j, 1]
    bpz = -W[j, 2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        lam[j] = 1.0
        idx[0] = j
        return 1
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        lam[i] = 1.0 - t
        lam[j] = t
        idx[0] = i
        idx[1] = j
        return 2
    cpx = -W[k, 0]
    cpy = -W[k, 1]
    cpz = -W[k, 2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        lam[k] = 1.0
        idx[0] = k
        return 1
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        lam[i] = 1.0 - t
        lam[k] = t
        idx[0] = i
        idx[1] = k
        return 2
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        lam[j] = 1.0 - t
        lam[k] = t
        idx[0] = j
        idx[1] = k
        return 2
    denom = va + vb + vc
    if not denom > TINY:  # degenerate (collinear) triangle: its best edge
        return _segment(W, A, B, lam, i, j, idx) if d1 * d1 <= d2 * d2 else _segment(W, A, B, lam, i, k, idx)
    v = vb / denom
    w = vc / denom
    lam[i] = 1.0 - v - w
    lam[j] = v
    lam[k] = w
    idx[0] = i
    idx[1] = j
    idx[2] = k
    return 3


@kernel
def _normal(W, i, j, k):
    """``(W[j] - W[i]) x (W[k] - W[i])``: the normal of triangle ``W[i] W[j] W[k]`` (unnormalised;
    counter-clockwise seen from where it points)."""
    abx = W[j, 0] - W[i, 0]
    aby = W[j, 1] - W[i, 1]
    abz = W[j, 2] - W[i, 2]
    acx = W[k, 0] - W[i, 0]
    acy = W[k, 1] - W[i, 1]
    acz = W[k, 2] - W[i, 2]
    return aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx


@kernel
def _outside(W, i, j, k, opposite):
    """Whether the origin and ``W[opposite]`` lie on different sides of plane ``W[i] W[j] W[k]``
    (the origin strictly outside the tetrahedron through that face)."""
    nx, ny, nz = _normal(W, i, j, k)
    sign_p = -(W[i, 0] * nx + W[i, 1] * ny + W[i, 2] * nz)
    sign_d = (W[opposite, 0] - W[i, 0]) * nx + (W[opposite, 1] - W[i, 1]) * ny + (W[opposite, 2] - W[i, 2]) * nz
    return sign_p * sign_d < 0.0


@kernel
def _closest(W, A, B, lam, count, idx, best_idx, best_lam, every_face):
    """Reduce the simplex ``W[:count]`` to the smallest sub-simplex holding its point closest
    to the origin, with that point's barycentric weights in ``lam``; returns the new count (0:
    the origin is inside a tetrahedron). ``every_face``: a tetrahedron's nearest face, whatever
    the sign tests say (for a tetrahedron too flat for them)."""
    for k in range(4):
        lam[k] = 0.0
    if count == 1:
        lam[0] = 1.0
        return 1
    if count == 2:
        kept = _segment(W, A, B, lam, np.int64(0), np.int64(1), idx)
        return _keep(W, A, B, lam, idx, kept)
    if count == 3:
        kept = _triangle(W, A, B, lam, np.int64(0), np.int64(1), np.int64(2), idx)
        return _keep(W, A, B, lam, idx, kept)
    # tetrahedron: the nearest of the faces the origin is outside of
    best = np.inf
    best_count = np.int64(0)  # int64 from the start: numba would first type the call of _keep with a literal 0
    for face in range(4):  # the face opposite vertex ``face``
        i = 1 if face == 0 else 0
        j = 1 if face == 2 or face == 3 else 2
        k = 2 if face == 3 else 3
        if face == 1:
            j = 2
        if not every_face and not _outside(W, i, j, k, face):
            continue
        for m in range(4):
            lam[m] = 0.0
        kept = _triangle(W, A, B, lam, i, j, k, idx)
        px = 0.0
        py = 0.0
        pz = 0.0
        for m in range(kept):
            px += lam[idx[m]] * W[idx[m], 0]
            py += lam[idx[m]] * W[idx[m], 1]
            pz += lam[idx[m]] * W[idx[m], 2]
        dd = px * px + py * py + pz * pz
        if dd < best:
            best = dd
            best_count = kept
            for m in range(kept):
                best_idx[m] = idx[m]
                best_lam[m] = lam[idx[m]]
    if best_count == 0:
        return 0
    for m in range(4):
        lam[m] = 0.0
    for m in range(best_count):
        lam[best_idx[m]] = best_lam[m]
        idx[m] = best_idx[m]
    return _keep(W, A, B, lam, idx, best_count)


@kernel
def core_distance(sa, sb, vertices, buf, witness):
    """The distance between the cores of posed shapes ``sa`` and ``sb``, their closest points
    into ``witness (2, 3)`` (``sa``'s, then ``sb``'s); when they intersect, minus their
    penetration depth and its deepest points (:func:`_penetration`). ``buf``:
    :func:`gjk_buffers`."""
    W, A, B, lam, tmp, kept, kept_lam = buf[0], buf[1], buf[2], buf[3], buf[4], buf[5], buf[6]
    pa = tmp[0]
    pb = tmp[1]
    v = tmp[2]
    idx = np.empty(4, dtype=np.int64)
    best_idx = np.empty(4, dtype=np.int64)
    best_lam = np.empty(4)
    v[0] = sa[POS] - sb[POS]
    v[1] = sa[POS + 1] - sb[POS + 1]
    v[2] = sa[POS + 2] - sb[POS + 2]
    if v[0] * v[0] + v[1] * v[1] + v[2] * v[2] <= TINY:
        v[0] = 1.0
    count = 0
    vv = np.inf
    scale = 0.0  # the largest |w|^2 seen: what "the origin is on the simplex" is relative to
    for _ in range(MAX_ITERATIONS):
        support(sa, vertices, -v[0], -v[1], -v[2], pa)
        support(sb, vertices, v[0], v[1], v[2], pb)
        wx = pa[0] - pb[0]
        wy = pa[1] - pb[1]
        wz = pa[2] - pb[2]
        scale = max(scale, wx * wx + wy * wy + wz * wz)
        if count > 0:
            vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
            if vv - (v[0] * wx + v[1] * wy + v[2] * wz) <= RELATIVE_TOLERANCE * vv:
                break  # the support point brings the distance no closer
            repeat = False
            for k in range(count):
                if W[k, 0] == wx and W[k, 1] == wy and W[k, 2] == wz:
                    repeat = True
            if repeat:
                break
        kept_count = count  # the simplex before the step: a step that gains nothing is undone
        for k in range(count):
            kept_lam[k] = lam[k]
            for r in range(3):
                kept[0, k, r] = W[k, r]
                kept[1, k, r] = A[k, r]
                kept[2, k, r] = B[k, r]
        W[count, 0] = wx
        W[count, 1] = wy
        W[count, 2] = wz
        for r in range(3):
            A[count, r] = pa[r]
            B[count, r] = pb[r]
        count += 1
        count = _closest(W, A, B, lam, count, idx, best_idx, best_lam, np.bool_(False))
        if count == 0:
            # The origin can be inside only if the new point lies beyond it: the simplex before
            # lies where v . x >= |v|^2. Else a nearly flat tetrahedron (support points crowding
            # on a cylinder's rim, or cores nearly touching) fooled the sign tests, and cores
            # 0.1 m apart read as intersecting: its nearest face goes on instead.
            if v[0] * wx + v[1] * wy + v[2] * wz <= RELATIVE_TOLERANCE * vv:
                break  # the origin is inside: the cores intersect
            count = _closest(W, A, B, lam, np.int64(4), idx, best_idx, best_lam, np.bool_(True))
        nx = 0.0
        ny = 0.0
        nz = 0.0
        for k in range(count):
            nx += lam[k] * W[k, 0]
            ny += lam[k] * W[k, 1]
            nz += lam[k] * W[k, 2]
        new = nx * nx + ny * ny + nz * nz
        if not new < vv:  # (vv is inf on the first step)
            # no progress (rounding, or a nearly flat tetrahedron whose faces the sign tests
            # misjudge): the last step's simplex and point stand
            count = kept_count
            for k in range(count):
                lam[k] = kept_lam[k]
                for r in range(3):
                    W[k, r] = kept[0, k, r]
                    A[k, r] = kept[1, k, r]
                    B[k, r] = kept[2, k, r]
            break
        v[0] = nx
        v[1] = ny
        v[2] = nz
        if count == 4 or new <= 1e-24 * scale:
            count = 0 if count == 4 else count
            break
    if count == 0:  # the origin is inside the tetrahedron W: the cores intersect
        depth = _penetration(sa, sb, vertices, buf, np.int64(4), witness)
        if depth > 0.0:
            return -depth
        # a flat tetrahedron (cores that barely touch): one point of the overlap for both, no normal
        for r in range(3):
            acc = 0.0
            for k in range(4):
                acc += 0.125 * (A[k, r] + B[k, r])
            witness[0, r] = acc
            witness[1, r] = acc
        return 0.0
    for r in range(3):
        acc_a = 0.0
        acc_b = 0.0
        for k in range(count):
            acc_a += lam[k] * A[k, r]
            acc_b += lam[k] * B[k, r]
        witness[0, r] = acc_a
        witness[1, r] = acc_b
    dx = witness[0, 0] - witness[1, 0]
    dy = witness[0, 1] - witness[1, 1]
    dz = witness[0, 2] - witness[1, 2]
    gap = np.sqrt(dx * dx + dy * dy + dz * dz)
    if gap <= 1e-9 * np.sqrt(scale):  # the origin on a smaller simplex: touching, or inside
        depth = _penetration(sa, sb, vertices, buf, np.int64(count), tmp[5:7])
        if depth > 0.0:
            for r in range(3):
                witness[0, r] = tmp[5, r]
                witness[1, r] = tmp[6, r]
            return -depth
    return gap


@kernel
def _face(P, faces, planes, f, i, j, k):
    """Make face ``f`` of EPA's polytope the triangle ``P[i] P[j] P[k]`` (counter-clockwise seen
    from outside): its unit normal and the origin's distance to its plane into ``planes[f]``.
    False when the three points are (nearly) on one line."""
    nx, ny, nz = _normal(P, i, j, k)
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    faces[f, 0] = i
    faces[f, 1] = j
    faces[f, 2] = k
    faces[f, 3] = 1
    uu = (P[j, 0] - P[i, 0]) ** 2 + (P[j, 1] - P[i, 1]) ** 2 + (P[j, 2] - P[i, 2]) ** 2
    vv = (P[k, 0] - P[i, 0]) ** 2 + (P[k, 1] - P[i, 1]) ** 2 + (P[k, 2] - P[i, 2]) ** 2
    if not norm > 1e-14 * np.sqrt(uu * vv):
        return False
    planes[f, 0] = nx / norm
    planes[f, 1] = ny / norm
    planes[f, 2] = nz / norm
    planes[f, 3] = (nx * P[i, 0] + ny * P[i, 1] + nz * P[i, 2]) / norm
    return True


@kernel
def _support_point(sa, sb, vertices, dx, dy, dz, points, m, tmp):
    """Point ``m`` of EPA's ``points``: the cores' difference farthest along ``(dx, dy, dz)``,
    and each core's point behind it."""
    pa = tmp[3]
    pb = tmp[4]
    support(sa, vertices, dx, dy, dz, pa)
    support(sb, vertices, -dx, -dy, -dz, pb)
    for r in range(3):
        points[0, m, r] = pa[r] - pb[r]
        points[1, m, r] = pa[r]
        points[2, m, r] = pb[r]


@kernel
def _penetration(sa, sb, vertices, buf, count, witness):
    """The penetration depth of cores that GJK found touching or intersecting (how far apart
    they must move to touch) by the expanding polytope algorithm (EPA; van den Bergen 2001, as
    coal does it), and the deepest points of ``sa``'s and ``sb``'s cores into ``witness (2, 3)``
    (the depth apart; the cores separate fastest moving ``sa`` from its point towards ``sb``'s).
    It starts from GJK's simplex ``buf[0][:count]``, which holds the origin: a tetrahedron
    (``count`` 4), or else a triangle (support points added off the line or the point) and the
    support point on one side of it, if the difference reaches beyond it on both. 0 when the
    origin is on the difference's boundary (touching), -1 when the simplex is flat (the
    witnesses are then left alone)."""
    W, A, B, tmp = buf[0], buf[1], buf[2], buf[4]
    # horizon: per edge of the horizon its two points and the neighbour across; column 3 the
    # search's stack, column 4 the faces gone (whose slots the new faces take)
    points, faces, planes, horizon = buf[7], buf[8], buf[9], buf[10]
    P, PA, PB = points[0], points[1], points[2]
    size = 0.0
    for m in range(count):
        for r in range(3):
            P[m, r] = W[m, r]
            PA[m, r] = A[m, r]
            PB[m, r] = B[m, r]
        size = max(size, np.sqrt(P[m, 0] * P[m, 0] + P[m, 1] * P[m, 1] + P[m, 2] * P[m, 2]))
    n_points = count
    for axis in range(6):  # a point: a second one, along the axes
        if n_points != 1:
            break
        sign = 1.0 if axis < 3 else -1.0
        along_x = sign if axis % 3 == 0 else 0.0
        along_y = sign if axis % 3 == 1 else 0.0
        along_z = sign if axis % 3 == 2 else 0.0
        _support_point(sa, sb, vertices, along_x, along_y, along_z, points, np.int64(1), tmp)
        gap = np.sqrt((P[1, 0] - P[0, 0]) ** 2 + (P[1, 1] - P[0, 1]) ** 2 + (P[1, 2] - P[0, 2]) ** 2)
        size = max(size, gap)
        if gap > 1e-9 * size:
            n_points = 2
    if n_points == 2:  # a segment: a third point off its line, along two perpendiculars
        ux = P[1, 0] - P[0, 0]
        uy = P[1, 1] - P[0, 1]
        uz = P[1, 2] - P[0, 2]
        ex = 1.0 if abs(ux) <= abs(uy) and abs(ux) <= abs(uz) else 0.0
        ey = 1.0 if ex == 0.0 and abs(uy) <= abs(uz) else 0.0
        ez = 1.0 - ex - ey
        d1x = uy * ez - uz * ey
        d1y = uz * ex - ux * ez
        d1z = ux * ey - uy * ex
        d2x = uy * d1z - uz * d1y
        d2y = uz * d1x - ux * d1z
        d2z = ux * d1y - uy * d1x
        uu = ux * ux + uy * uy + uz * uz
        for trial in range(4):
            sign = 1.0 if trial % 2 == 0 else -1.0
            dx, dy, dz = (d1x, d1y, d1z) if trial < 2 else (d2x, d2y, d2z)
            _support_point(sa, sb, vertices, sign * dx, sign * dy, sign * dz, points, np.int64(2), tmp)
            vx = P[2, 0] - P[0, 0]
            vy = P[2, 1] - P[0, 1]
            vz = P[2, 2] - P[0, 2]
            along = (vx * ux + vy * uy + vz * uz) / uu
            off = np.sqrt((vx - along * ux) ** 2 + (vy - along * uy) ** 2 + (vz - along * uz) ** 2)
            size = max(size, np.sqrt(P[2, 0] ** 2 + P[2, 1] ** 2 + P[2, 2] ** 2))
            if off > 1e-9 * size:
                n_points = 3
                break
    if n_points < 3:
        return -1.0
    if n_points == 3:  # a triangle through the origin: a tetrahedron on it, if the difference has volume there
        if not _face(P, faces, planes, np.int64(0), np.int64(0), np.int64(1), np.int64(2)):
            return -1.0
        nx = planes[0, 0]
        ny = planes[0, 1]
        nz = planes[0, 2]
        _support_point(sa, sb, vertices, -nx, -ny, -nz, points, np.int64(3), tmp)
        below = nx * (P[0, 0] - P[3, 0]) + ny * (P[0, 1] - P[3, 1]) + nz * (P[0, 2] - P[3, 2])
        _support_point(sa, sb, vertices, nx, ny, nz, points, np.int64(3), tmp)
        above = nx * (P[3, 0] - P[0, 0]) + ny * (P[3, 1] - P[0, 1]) + nz * (P[3, 2] - P[0, 2])
        size = max(size, np.sqrt(P[3, 0] ** 2 + P[3, 1] ** 2 + P[3, 2] ** 2))
        if not (above > 1e-9 * size and below > 1e-9 * size):
            return 0.0  # the difference is flat on one side: the origin is on its boundary
        n_points = 4  # convex, the origin on its face 0 1 2: EPA grows it from there
    # the first polytope's faces, each turned away from the centroid
    cx = 0.0
    cy = 0.0
    cz = 0.0
    for m in range(n_points):
        cx += P[m, 0] / n_points
        cy += P[m, 1] / n_points
        cz += P[m, 2] / n_points
    n_faces = 4
    for f in range(n_faces):  # the face opposite point f
        i = 1 if f == 0 else 0
        j = 1 if f >= 2 else 2
        k = 2 if f == 3 else 3
        if not _face(P, faces, planes, f, i, j, k):
            return -1.0
        if planes[f, 0] * cx + planes[f, 1] * cy + planes[f, 2] * cz > planes[f, 3]:
            _face(P, faces, planes, f, i, k, j)
    for f in range(n_faces):  # each edge's neighbour: the face that runs it the other way
        for e in range(3):
            a = faces[f, e]
            b = faces[f, (e + 1) % 3]
            faces[f, 4 + e] = -1
            for h in range(n_faces):
                for eh in range(3):
                    if h != f and faces[h, eh] == b and faces[h, (eh + 1) % 3] == a:
                        faces[f, 4 + e] = 3 * h + eh
            if faces[f, 4 + e] < 0:
                return -1.0
    # the nearest face (its points, normal and distance), kept as the polytope changes
    i = 0
    j = 0
    k = 0
    nx = 0.0
    ny = 0.0
    nz = 0.0
    depth = 0.0
    for _ in range(EPA_MAX_POINTS):
        best = -1
        for f in range(n_faces):
            if faces[f, 3] == 1 and (best < 0 or planes[f, 3] < planes[best, 3]):
                best = f
        if planes[best, 3] < depth - EPA_TOLERANCE * size:
            break  # the nearest face came nearer: rounding broke the polytope; the last one stands
        i = faces[best, 0]
        j = faces[best, 1]
        k = faces[best, 2]
        nx = planes[best, 0]
        ny = planes[best, 1]
        nz = planes[best, 2]
        depth = max(planes[best, 3], 0.0)  # a lower bound: the polytope lies inside the difference
        if n_points == EPA_MAX_POINTS:
            break
        _support_point(sa, sb, vertices, nx, ny, nz, points, n_points, tmp)
        wx = P[n_points, 0]
        wy = P[n_points, 1]
        wz = P[n_points, 2]
        if nx * wx + ny * wy + nz * wz - depth <= EPA_TOLERANCE * size:
            break  # the nearest face is on the boundary of the cores' difference
        new = n_points
        # The faces the new point sees go: the nearest face, then, depth first across its edges,
        # each neighbour it sees (one connected region, even where rounding makes nearly coplanar
        # faces on a cylinder disagree). The edges to faces that stay are the horizon, met in
        # order around it (van den Bergen's silhouette; the recursion kept on a stack).
        faces[best, 3] = 0
        horizon[0, 4] = best
        removed = 1
        top = 0
        for e in range(2, -1, -1):
            horizon[top, 3] = faces[best, 4 + e]
            top += 1
        n_edges = 0
        while top > 0:
            top -= 1
            across = horizon[top, 3]
            g = across // 3
            eg = across % 3
            if faces[g, 3] == 0:
                continue  # gone already: the edge is inside the region
            i0 = faces[g, 0]
            seen = planes[g, 0] * (wx - P[i0, 0]) + planes[g, 1] * (wy - P[i0, 1]) + planes[g, 2] * (wz - P[i0, 2])
            if seen > EPA_TOLERANCE * size:
                faces[g, 3] = 0
                horizon[removed, 4] = g
                removed += 1
                horizon[top, 3] = faces[g, 4 + (eg + 2) % 3]
                horizon[top + 1, 3] = faces[g, 4 + (eg + 1) % 3]
                top += 2
            else:  # g stays: its edge eg, run the other way, is on the horizon
                horizon[n_edges, 0] = faces[g, (eg + 1) % 3]
                horizon[n_edges, 1] = faces[g, eg]
                horizon[n_edges, 2] = across
                n_edges += 1
        added = max(n_edges - removed, 0)
        closed = n_edges >= 3
        for m in range(n_edges):
            closed = closed and horizon[m, 1] == horizon[(m + 1) % n_edges, 0]
        if not closed or n_faces + added > EPA_MAX_FACES:
            # rounding: the point sees too little, or a region that is not a disc; or no room: the
            # nearest face so far stands, on the polytope as it was
            for m in range(removed):
                faces[horizon[m, 4], 3] = 1
            break
        n_points += 1
        grown = True
        for m in range(n_edges):  # the new faces in the slots of those gone, then new slots
            slot = horizon[m, 4] if m < removed else n_faces + m - removed
            horizon[m, 3] = slot
            grown = grown and _face(P, faces, planes, slot, horizon[m, 0], horizon[m, 1], np.int64(new))
        n_faces += added
        for m in range(n_edges):  # neighbours: the face that stays, and the new faces on either side
            f = horizon[m, 3]
            after = horizon[(m + 1) % n_edges, 3]
            across = horizon[m, 2]
            faces[f, 4] = across
            faces[across // 3, 4 + across % 3] = 3 * f
            faces[f, 5] = 3 * after + 2
            faces[after, 6] = 3 * f + 1
        if not grown:
            break  # a sliver face: the polytope no longer holds; the last nearest face stands
    # the origin's projection on the nearest face, in barycentric weights of its points
    d00 = 0.0
    d01 = 0.0
    d11 = 0.0
    d20 = 0.0
    d21 = 0.0
    for r in range(3):
        e0 = P[j, r] - P[i, r]
        e1 = P[k, r] - P[i, r]
        e2 = (nx if r == 0 else ny if r == 1 else nz) * depth - P[i, r]
        d00 += e0 * e0
        d01 += e0 * e1
        d11 += e1 * e1
        d20 += e2 * e0
        d21 += e2 * e1
    denominator = d00 * d11 - d01 * d01
    lj = (d11 * d20 - d01 * d21) / denominator
    lk = (d00 * d21 - d01 * d20) / denominator
    li = 1.0 - lj - lk
    for r in range(3):
        witness[0, r] = li * PA[i, r] + lj * PA[j, r] + lk * PA[k, r]
        witness[1, r] = li * PB[i, r] + lj * PB[j, r] + lk * PB[k, r]
    return depth


@kernel
def _ends(shape, out):
    """The ends of a point or segment core into ``out (2, 3)`` (a point's twice)."""
    h = shape[DIMS] if int(shape[KIND]) == SEGMENT else 0.0
    for r in range(3):
        axis = shape[ROT + 3 * r + 2]
        out[0, r] = shape[POS + r] - h * axis
        out[1, r] = shape[POS + r] + h * axis


@kernel
def segment_distance(sa, sb, tmp, witness):
    """The distance between point or segment cores in closed form (the closest points of two
    segments, Ericson 5.1.9, clamped), their closest points into ``witness (2, 3)``. ``tmp (8,
    3)`` scratch."""
    P = tmp[0:2]
    Q = tmp[2:4]
    _ends(sa, P)
    _ends(sb, Q)
    d1x = P[1, 0] - P[0, 0]
    d1y = P[1, 1] - P[0, 1]
    d1z = P[1, 2] - P[0, 2]
    d2x = Q[1, 0] - Q[0, 0]
    d2y = Q[1, 1] - Q[0, 1]
    d2z = Q[1, 2] - Q[0, 2]
    rx = P[0, 0] - Q[0, 0]
    ry = P[0, 1] - Q[0, 1]
    rz = P[0, 2] - Q[0, 2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    s = 0.0
    t = 0.0
    if a <= TINY and e <= TINY:
        pass
    elif a <= TINY:
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = d1x * rx + d1y * ry + d1z * rz
        if e <= TINY:
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = d1x * d2x + d1y * d2y + d1z * d2z
            denom = a * e - b * b
            if denom > 0.0:
                s = min(max((b * f - c * e) / denom, 0.0), 1.0)
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((b - c) / a, 0.0), 1.0)
    for r in range(3):
        witness[0, r] = P[0, r] + s * (P[1, r] - P[0, r])
        witness[1, r] = Q[0, r] + t * (Q[1, r] - Q[0, r])
    dx = witness[0, 0] - witness[1, 0]
    dy = witness[0, 1] - witness[1, 1]
    dz = witness[0, 2] - witness[1, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@kernel
def shape_distance(sa, sb, vertices, buf, witness):
    """Signed distance between posed shapes ``sa`` and ``sb``: their cores' distance less both
    radii (negative when the swept spheres overlap; less their penetration depth too when the
    cores intersect). ``witness (2, 3)`` receives the closest (deepest) points of the cores.
    Points and segments (spheres and capsules) in closed form, the rest by GJK and EPA."""
    if int(sa[KIND]) <= SEGMENT and int(sb[KIND]) <= SEGMENT:
        core = segment_distance(sa, sb, buf[4], witness)
    else:
        core = core_distance(sa, sb, vertices, buf, witness)
    return core - sa[RADIUS] - sb[RADIUS]


@kernel
def distances_many(shapes_a, shapes_b, vertices, out, witness):
    """Signed distances of posed shape pairs ``shapes_a[k]``, ``shapes_b[k]`` into ``out (K,)``
    and their witness points into ``witness (K, 2, 3)`` (for tests and tools)."""
    buf = gjk_buffers()
    for k in range(shapes_a.shape[0]):
        out[k] = shape_distance(shapes_a[k], shapes_b[k], vertices, buf, witness[k])


# --- Shapes on a moving robot (the planner's step loop) -------------------------------------


@kernel
def pose_into(shapes, s, att, com, A0, com_w, out, d):
    """Pose shape row ``s`` of ``shapes`` into row ``d`` of ``out``, in the planner's base frame
    (the carrier's attitude the identity, the system CoM at the origin): a body's shape by its
    attitude ``att[b]`` and CoM ``com[b]`` (the kinematics buffers), an obstacle's (world pose)
    by ``x_b = A0^T (x_w - com_w)``. (Indices, no row views or temporaries: it runs for every
    shape at every sample.)"""
    body = int(shapes[s, BODY])
    for c in range(SHAPE_WIDTH):
        out[d, c] = shapes[s, c]
    for r in range(3):
        if body == WORLD:
            r0 = A0[0, r]
            r1 = A0[1, r]
            r2 = A0[2, r]
            pr = -(r0 * com_w[0] + r1 * com_w[1] + r2 * com_w[2])
        else:
            r0 = att[body, r, 0]
            r1 = att[body, r, 1]
            r2 = att[body, r, 2]
            pr = com[body, r]
        out[d, POS + r] = pr + r0 * shapes[s, POS] + r1 * shapes[s, POS + 1] + r2 * shapes[s, POS + 2]
        for c in range(3):
            out[d, ROT + 3 * r + c] = r0 * shapes[s, ROT + c] + r1 * shapes[s, ROT + 3 + c] + r2 * shapes[s, ROT + 6 + c]


@kernel
def pose_all(shapes, att, com, A0, com_w, posed):
    """:func:`pose_into` for every shape into ``posed (S, SHAPE_WIDTH)``."""
    for s in range(shapes.shape[0]):
        pose_into(shapes, s, att, com, A0, com_w, posed, s)


@kernel
def lower_bound(posed, a, b):
    """A lower bound of the distance between posed shapes ``a`` and ``b``: their bounding
    spheres' distance. (Indices rather than rows: a row view costs reference counting in the
    planner's inner loop.)"""
    dx = posed[a, POS] - posed[b, POS]
    dy = posed[a, POS + 1] - posed[b, POS + 1]
    dz = posed[a, POS + 2] - posed[b, POS + 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz) - posed[a, BOUND] - posed[b, BOUND]


@kernel
def add_point_row(body, x, nx, ny, nz, sign, ch_slide, kin, bm, row):
    """``row (n,) += sign * d(n . v_x)/d(qd)``: how the velocity of point ``x (3,)`` fixed to
    ``body`` (planner base frame), along ``(nx, ny, nz)``, depends on the joint rates (the base's
    reaction through ``bm`` included); nothing for an obstacle."""
    if body == WORLD:
        return
    _, com, jpos, jaxis, _, _ = kin
    n = row.shape[0]
    # n . (v_0 + w_0 x (x - r_0)) = n . v_0 + ((x - r_0) x n) . w_0
    rx = x[0] - com[0, 0]
    ry = x[1] - com[0, 1]
    rz = x[2] - com[0, 2]
    mx = ry * nz - rz * ny
    my = rz * nx - rx * nz
    mz = rx * ny - ry * nx
    for j in range(n):
        row[j] += sign * (nx * bm[0, j] + ny * bm[1, j] + nz * bm[2, j] + mx * bm[3, j] + my * bm[4, j] + mz * bm[5, j])
    for j in range(body):
        kx = jaxis[j, 0]
        ky = jaxis[j, 1]
        kz = jaxis[j, 2]
        if ch_slide[j] != 0.0:
            row[j] += sign * (nx * kx + ny * ky + nz * kz)
        else:
            ex = x[0] - jpos[j, 0]
            ey = x[1] - jpos[j, 1]
            ez = x[2] - jpos[j, 2]
            # n . (k x e)
            row[j] += sign * (nx * (ky * ez - kz * ey) + ny * (kz * ex - kx * ez) + nz * (kx * ey - ky * ex))


@kernel
def distance_rate_row(sa, sb, witness, d, ch_slide, kin, bm, row):
    """``row (n,)``: the gradient of the signed distance ``d`` between posed shapes ``sa`` and
    ``sb`` with respect to the joint rates, ``d_dot = row . qd``, from their cores' closest
    points ``witness (2, 3)``: the normal runs from ``sb``'s point to ``sa``'s, or, where the
    cores intersect (``d`` below minus both radii), from ``sa``'s deepest point to ``sb``'s (the
    way out). False (and a zero row) when the points coincide (no normal)."""
    for j in range(row.shape[0]):
        row[j] = 0.0
    dx = witness[0, 0] - witness[1, 0]
    dy = witness[0, 1] - witness[1, 1]
    dz = witness[0, 2] - witness[1, 2]
    norm = np.sqrt(dx * dx + dy * dy + dz * dz)
    if not norm > 0.0:
        return False
    if d + sa[RADIUS] + sb[RADIUS] < 0.0:
        norm = -norm
    nx = dx / norm
    ny = dy / norm
    nz = dz / norm
    add_point_row(int(sa[BODY]), witness[0], nx, ny, nz, 1.0, ch_slide, kin, bm, row)
    add_point_row(int(sb[BODY]), witness[1], nx, ny, nz, -1.0, ch_slide, kin, bm, row)
    return True


@kernel
def clearance_buffers(n, n_shapes, n_pairs):
    """Scratch of a plan's clearance checks: ``(posed (S, SHAPE_WIDTH), dist (P,), exact (P,)
    1.0 where ``dist`` is exact (else a lower bound), witness (P, 2, 3), prev_dist (P,),
    prev_speed (P,), rows (P, n), rhs (P,), gjk buffers, stats (8,), pair_posed (2,
    SHAPE_WIDTH), pair_witness (2, 3), stack (64, 6), grad (n,), step_speed (P,), reach (S,
    n + 1))``."""
    return (
        np.empty((n_shapes, SHAPE_WIDTH)),
        np.empty(n_pairs),
        np.empty(n_pairs),
        np.empty((n_pairs, 2, 3)),
        np.empty(n_pairs),
        np.empty(n_pairs),
        np.empty((n_pairs, n)),
        np.empty(n_pairs),
        gjk_buffers(),
        np.empty(8),
        np.empty((2, SHAPE_WIDTH)),
        np.empty((2, 3)),
        np.empty((64, 6)),
        np.empty(n),
        np.zeros(n_pairs),
        np.empty((n_shapes, n + 1)),
    )


# stats of a plan's clearance (the ``stats`` buffer)
MIN_D, T_MIN_D, MIN_PAIR, HIT_PAIR, T_HIT, HIT_D = 0, 1, 2, 3, 4, 5


@kernel
def reset_stats(stats):
    stats[MIN_D] = np.inf
    stats[T_MIN_D] = np.nan
    stats[MIN_PAIR] = -1.0
    stats[HIT_PAIR] = -1.0
    stats[T_HIT] = np.nan
    stats[HIT_D] = np.nan


@kernel
def note_distance(stats, d, t, pair, clearance):
    """Count a distance ``d`` of ``pair`` at time ``t``: the smallest so far, and the first below
    the clearance."""
    if d < stats[MIN_D]:
        stats[MIN_D] = d
        stats[T_MIN_D] = t
        stats[MIN_PAIR] = pair
    if d < clearance and stats[HIT_PAIR] < 0.0:
        stats[HIT_PAIR] = pair
        stats[T_HIT] = t
        stats[HIT_D] = d


@kernel(inline=True)
def sample_distances(pairs, vertices, cutoff, clearance, dt, first, refine, buf):
    """Each pair's distance at a sample (shapes posed in ``buf``'s ``posed``): a lower bound
    first, the larger of the bounding spheres' distance and (after the first sample) the last
    sample's value less the step's speed bound times ``dt`` (``prev_dist``, ``step_speed``); then
    exact (GJK or closed form) where that bound is below ``cutoff``, below the clearance plus the
    step's travel (the check between samples may need it), or, with ``refine``, below the
    smallest exact distance of the sample (so that it is exact). Returns that smallest exact
    distance and its pair (``inf``, -1 when none was exact)."""
    posed, dist, exact, witness, prev_dist = buf[0], buf[1], buf[2], buf[3], buf[4]
    gjk, step_speed = buf[8], buf[14]
    n_pairs = pairs.shape[0]
    best = np.inf
    best_pair = -1
    for p in range(n_pairs):
        bound = lower_bound(posed, pairs[p, 0], pairs[p, 1])
        if not first:
            bound = max(bound, prev_dist[p] - step_speed[p] * dt)
        dist[p] = bound
        exact[p] = 0.0
        if bound < cutoff or bound < clearance + step_speed[p] * dt:
            d = unlinked(shape_distance, (posed[pairs[p, 0]], posed[pairs[p, 1]], vertices, gjk, witness[p]))
            dist[p] = d
            exact[p] = 1.0
            if d < best:
                best = d
                best_pair = p
    while refine:  # the nearest bound below the best exact distance, until none is
        nearest = -1
        for p in range(n_pairs):
            if exact[p] == 0.0 and dist[p] < best and (nearest < 0 or dist[p] < dist[nearest]):
                nearest = p
        if nearest < 0:
            break
        d = unlinked(shape_distance, (posed[pairs[nearest, 0]], posed[pairs[nearest, 1]], vertices, gjk, witness[nearest]))
        dist[nearest] = d
        exact[nearest] = 1.0
        if d < best:
            best = d
            best_pair = nearest
    return best, best_pair


@kernel
def joint_reach(posed, ch_slide, kin, reach):
    """``reach (S, n + 1)``: for each posed shape, how fast its points can move per unit rate of
    each joint that moves its body (m per rad: its distance from the joint's axis line plus its
    bounding radius; 1 for a prismatic joint; 0 for the joints that do not move it), and in the
    last column its bounding distance from the carrier's CoM (for the carrier's rotation)."""
    _, com, jpos, jaxis, _, _ = kin
    n = jpos.shape[0]
    for s in range(posed.shape[0]):
        body = int(posed[s, BODY])
        cx = posed[s, POS]
        cy = posed[s, POS + 1]
        cz = posed[s, POS + 2]
        extent = posed[s, BOUND]
        for j in range(n):
            if j >= body:  # also every joint for an obstacle (body -1): it does not move
                reach[s, j] = 0.0
            elif ch_slide[j] != 0.0:
                reach[s, j] = 1.0
            else:
                ex = cx - jpos[j, 0]
                ey = cy - jpos[j, 1]
                ez = cz - jpos[j, 2]
                kx = jaxis[j, 0]
                ky = jaxis[j, 1]
                kz = jaxis[j, 2]
                px = ky * ez - kz * ey
                py = kz * ex - kx * ez
                pz = kx * ey - ky * ex
                reach[s, j] = np.sqrt(px * px + py * py + pz * pz) + extent
        dx = cx - com[0, 0]
        dy = cy - com[0, 1]
        dz = cz - com[0, 2]
        reach[s, n] = np.sqrt(dx * dx + dy * dy + dz * dz) + extent


@kernel
def pair_speeds(posed, pairs, reach, bm, qd, out):
    """``out (P,)``: a bound (m/s) of how fast each pair's distance changes under the joint rates
    ``qd``, from :func:`joint_reach`. Only what moves one shape relative to the other counts: the
    joints between two links' bodies (the carrier and the joints before both move them rigidly
    together), every joint up to a link for the carrier and that link, and the carrier's own
    motion (``bm (6, n)``, its twist per joint rate) against an obstacle."""
    n = qd.shape[0]
    v0 = 0.0
    w0 = 0.0
    vx = 0.0
    vy = 0.0
    vz = 0.0
    wx = 0.0
    wy = 0.0
    wz = 0.0
    for j in range(n):
        vx += bm[0, j] * qd[j]
        vy += bm[1, j] * qd[j]
        vz += bm[2, j] * qd[j]
        wx += bm[3, j] * qd[j]
        wy += bm[4, j] * qd[j]
        wz += bm[5, j] * qd[j]
    v0 = np.sqrt(vx * vx + vy * vy + vz * vz)
    w0 = np.sqrt(wx * wx + wy * wy + wz * wz)
    for p in range(pairs.shape[0]):
        a = pairs[p, 0]
        b = pairs[p, 1]
        body_a = int(posed[a, BODY])
        body_b = int(posed[b, BODY])
        if body_a > body_b:  # b the outer body (an obstacle, -1, is always the inner)
            a, b = b, a
            body_a, body_b = body_b, body_a
        speed = 0.0
        first = 0 if body_a <= 0 else body_a
        for j in range(first, body_b):
            speed += abs(qd[j]) * reach[b, j]
        if body_a < 0:  # an obstacle: the carrier's motion moves the other shape too
            speed += v0 + w0 * reach[b, n]
        out[p] = speed


#: m: the velocity dampers aim this far above the clearance: they hold the distance to first order
#: at the samples, and the margin absorbs the motion's curvature between them.
DAMPER_MARGIN = 0.002


@kernel
def avoidance_rows(posed, pairs, buf, ch_slide, kin, bm, influence, clearance, gain, dt):
    """The velocity dampers of the pairs closer than ``influence`` (exact distances), as rows
    ``C qd <= d`` of the bounded inverse's QP in ``buf``'s ``rows``/``rhs``: ``-d_dot <= gain
    (d - d_s) / dt`` with ``d_s`` the clearance plus :data:`DAMPER_MARGIN`, so a step consumes
    at most the fraction ``gain`` of a pair's excess over ``d_s`` (to first order; a pair below
    it is pushed back out). Returns how many."""
    dist, exact, witness, rows, rhs = buf[1], buf[2], buf[3], buf[6], buf[7]
    count = 0
    for p in range(pairs.shape[0]):
        if exact[p] == 0.0 or not dist[p] < influence:
            continue
        if not distance_rate_row(posed[pairs[p, 0]], posed[pairs[p, 1]], witness[p], dist[p], ch_slide, kin, bm, rows[count]):
            continue
        for j in range(rows.shape[1]):
            rows[count, j] = -rows[count, j]
        rhs[count] = gain * (dist[p] - clearance - DAMPER_MARGIN) / dt
        count += 1
    return count


#: m/rad: damps the ``clearance`` objective's rates where a pair's distance barely depends on
#: the joints (a pair the arm can hardly move apart is not pushed at unbounded rates).
PUSH_DAMPING = 0.05


@kernel
def clearance_push(posed, pairs, buf, ch_slide, kin, bm, influence, gain, z):
    """``z (n,)``: joint rates that raise the distance of each pair closer than ``influence`` at
    ``gain (influence - d)`` m/s (each pair's damped least-norm rates ``grad / (|grad|^2 +
    PUSH_DAMPING^2)`` times that, summed); the planner keeps their null-space part (the
    ``clearance`` secondary objective)."""
    dist, exact, witness, grad = buf[1], buf[2], buf[3], buf[13]
    n = z.shape[0]
    for j in range(n):
        z[j] = 0.0
    for p in range(pairs.shape[0]):
        if exact[p] == 0.0 or not dist[p] < influence:
            continue
        if not distance_rate_row(posed[pairs[p, 0]], posed[pairs[p, 1]], witness[p], dist[p], ch_slide, kin, bm, grad):
            continue
        norm2 = 0.0
        for j in range(n):
            norm2 += grad[j] * grad[j]
        if not norm2 > 0.0:
            continue
        scale = gain * (influence - dist[p]) / (norm2 + PUSH_DAMPING * PUSH_DAMPING)
        for j in range(n):
            z[j] += scale * grad[j]
