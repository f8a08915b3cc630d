"""The smooth pieces of a convex-piece row at a kink: a box hovering over a box, its bottom face
parallel to the top face below (every bottom vertex as low as the others)."""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin
from conftest import central_difference

from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.hull_pieces import NEAR, hull_row_pieces
from calib_oed.feasibility.hulls import HullPairs, LinkPieces

TABLE_TOP = 0.2  # [m]: the world box's top face
PIVOT = 0.3  # [m]: height of the two joints (about x, then y); the hovering box's centre
HALF = np.array([0.1, 0.05, 0.025])  # [m]: the hovering box's half sides
CLEARANCE = 0.01  # [m]


def _piece(name: str, body: int, half: np.ndarray, centre: np.ndarray) -> LinkPieces:
    eye = np.eye(3)[None]
    centre = np.asarray(centre, dtype=float)[None]
    return LinkPieces(name, body, (coal.Box(*(2 * half)),), eye, centre, centre, centre,
                      np.array([float(np.linalg.norm(half))]))


def _scene(x0: float = 0.0):
    """A two-joint arm (about x, then y, both at the pivot over (x0, 0)) carrying a box over a world
    box whose top face spans -0.4..0.4 m in x and y."""
    model = pin.Model()
    j1 = model.addJoint(0, pin.JointModelRX(), pin.SE3(np.eye(3), np.array([x0, 0.0, PIVOT])), "j1")
    model.addJoint(j1, pin.JointModelRY(), pin.SE3.Identity(), "j2")
    pieces = {"table": _piece("table", 0, np.array([0.4, 0.4, 0.1]), [0.0, 0.0, TABLE_TOP - 0.1]),
              "box": _piece("box", 2, HALF, [0.0, 0.0, 0.0])}
    return model, HullPairs(pieces, [("box", "table")])


def _row(model, hull, q):
    return hull.closest(compute_body_states(model, np.asarray(q, dtype=float)[None], jacobian=False),
                        [0]).dist[0, 0] - CLEARANCE


def _pieces(model, hull, q):
    states = compute_body_states(model, np.asarray(q, dtype=float)[None])
    return hull_row_pieces(hull, states, np.array([0]), np.array([0]), CLEARANCE)


def test_a_face_on_a_face_gives_one_piece_per_vertex_and_the_row_is_their_minimum():
    """At q = 0 the four bottom vertices tie: four pieces, each equal to the row; the row's one-sided
    slope along any direction is the least of the pieces' slopes (the first-order model the QP
    needs), while the row's own gradient is wrong along most directions."""
    model, hull = _scene()
    q0 = np.zeros(2)
    pieces = _pieces(model, hull, q0)
    g0 = _row(model, hull, q0)
    assert len(pieces.values) == 4 and np.allclose(pieces.values, g0, atol=1e-12)
    assert np.isclose(g0, PIVOT - HALF[2] - TABLE_TOP - CLEARANCE, atol=1e-12)
    states = compute_body_states(model, q0[None])
    _, own = hull.rows(states, CLEARANCE, jacobian=True)
    rng = np.random.default_rng(0)
    wrong = 0
    for v in rng.standard_normal((20, 2)):
        v /= np.linalg.norm(v)
        t = 1e-7
        slope = (_row(model, hull, t * v) - g0) / t
        assert abs(slope - np.min(pieces.jacobian @ v)) <= 1e-6, (v, slope)
        wrong += abs(slope - own[0, 0] @ v) > 1e-3
    assert wrong >= 10


def test_piece_gradients_against_central_differences():
    """Slightly tilted (the bottom vertices within NEAR of the lowest): every piece is the height of
    its vertex above the table's top plane, whose gradient central differences check."""
    model, hull = _scene()
    q = np.array([0.004, -0.003])
    pieces = _pieces(model, hull, q)
    corners = np.array([[sx, sy, -1.0] for sx in (-1, 1) for sy in (-1, 1)]) * HALF
    heights = compute_body_states(model, q[None], jacobian=False).points(np.full(4, 2), corners)[0, :, 2]
    assert len(pieces.values) == int(np.sum(heights <= heights.min() + NEAR)) >= 2
    for value, grad in zip(pieces.values, pieces.jacobian, strict=True):
        k = int(np.argmin(np.abs(heights - TABLE_TOP - CLEARANCE - value)))
        assert abs(heights[k] - TABLE_TOP - CLEARANCE - value) <= 1e-12

        def height(x, k=k):
            states = compute_body_states(model, np.asarray(x)[None], jacobian=False)
            return states.points(np.array([2]), corners[k:k + 1])[0, 0, 2] - TABLE_TOP - CLEARANCE

        assert np.allclose(grad, central_difference(height, q), atol=1e-9)
    # the row is the least piece
    assert np.isclose(_row(model, hull, q), pieces.values.min(), atol=1e-12)


def test_no_face_no_pieces():
    """Tilted by 0.3 rad about both axes, one vertex is lowest by far: no kink, no pieces."""
    model, hull = _scene()
    assert len(_pieces(model, hull, np.array([0.3, 0.3])).values) == 0


def test_an_overhanging_face_gives_pieces_where_the_edges_cross():
    """The box overhangs the table's edge at x = 0.4 m: the contact is the part of its bottom face over
    the table, with two corners at its vertices and two where its long edges cross the table's edge.
    The crossing pieces are edge-to-edge distances (checked against central differences of the
    distance of the two lines); the row's one-sided slope is the least piece slope."""
    model, hull = _scene(0.38)
    q0 = np.zeros(2)
    pieces = _pieces(model, hull, q0)
    g0 = _row(model, hull, q0)
    assert len(pieces.values) == 4 and np.allclose(pieces.values, g0, atol=1e-12)
    rng = np.random.default_rng(2)
    for v in rng.standard_normal((12, 2)):
        v /= np.linalg.norm(v)
        slope = (_row(model, hull, 1e-7 * v) - g0) / 1e-7
        assert abs(slope - np.min(pieces.jacobian @ v)) <= 1e-6, (v, slope)

    def edge_gap(x, sy):
        """Distance along the common normal of the box's bottom long edge at y = sy·HALF[1] and the
        table's top edge x = 0.4 m (both lines, signed up)."""
        states = compute_body_states(model, np.asarray(x)[None], jacobian=False)
        ends = states.points(np.array([2, 2]), np.array([[-HALF[0], sy * HALF[1], -HALF[2]],
                                                          [HALF[0], sy * HALF[1], -HALF[2]]]))[0]
        a0, da = ends[0], ends[1] - ends[0]
        b0, db = np.array([0.4, 0.0, TABLE_TOP]), np.array([0.0, 1.0, 0.0])
        n = np.cross(da, db)
        n *= np.sign(n[2]) / np.linalg.norm(n)
        return float(n @ (a0 - b0)) - CLEARANCE

    for sy in (-1.0, 1.0):  # each crossing piece is the gradient of an edge-to-edge distance
        assert np.isclose(edge_gap(q0, sy), g0, atol=1e-12)
        num = central_difference(lambda x, sy=sy: edge_gap(x, sy), q0)
        assert np.min(np.abs(pieces.jacobian - num).max(axis=1)) <= 1e-9, (sy, pieces.jacobian, num)
