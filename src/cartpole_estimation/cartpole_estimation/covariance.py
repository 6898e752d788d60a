"""The EKF's covariance algebra, (5.12)-(5.16), in scalar closed form on a packed symmetric P.

The filter's state is ``z = [x, m, x_dot, theta_dot, b]``: the cart position,
the pendulum angle *as the encoder measures it* ``m = theta - b``, the two
velocities, and the encoder's constant angle offset b (Appendix H; zero and
certain when the filter does not estimate it). In these coordinates the
measurement matrix stays ``H = [I_2 0]`` (5.18), and the offset enters only
the model: the accelerations are evaluated at ``theta = m + b``, so the
Jacobian F_k has for b the same column as for theta.

P (5x5, symmetric) is kept as the 15 entries of its upper triangle,
``(p00, p01, p02, p03, p04, p11, p12, p13, p14, p22, p23, p24, p33, p34, p44)``,
a tuple of floats: the small matrix products written out are several times
faster in CPython than numpy's. With ``p04 = p14 = p24 = p34 = p44 = 0`` and
no process noise on b, every b entry stays exactly zero and the other ten
are those of the thesis's 4-state filter, bit for bit. A test checks both
functions against the matrix form.

No ROS import.
"""
from __future__ import annotations

import math

from cartpole_core.model import wrap_angle

__all__ = ['predict_covariance', 'correct']

Packed = tuple[float, float, float, float, float, float, float, float, float, float, float,
               float, float, float, float]


def predict_covariance(pc: Packed, h: float, f21: float, f22: float, f23: float, f31: float,
                       f32: float, f33: float, q: tuple[float, ...]) -> Packed:
    """P_k|k-1 = F_k P F_k^T + Q (5.16), with Q = diag(q) (5 entries).

    ``F_k = [[1, 0, h, 0, 0], [0, 1, 0, h, 0], [0, f21, f22, f23, f21],
    [0, f31, f32, f33, f31], [0, 0, 0, 0, 1]]``: rows 3 and 4 are those of
    (5.19) from forward differences (5.21); the model accelerations do not
    depend on x (first column zero) and depend on b as on theta.
    """
    p00, p01, p02, p03, p04, p11, p12, p13, p14, p22, p23, p24, p33, p34, p44 = pc
    q0, q1, q2, q3, q4 = q
    # B = F_k P, the entries the upper triangle of B F_k^T needs.
    b00 = p00 + h * p02
    b01 = p01 + h * p12
    b02 = p02 + h * p22
    b03 = p03 + h * p23
    b04 = p04 + h * p24
    b11 = p11 + h * p13
    b12 = p12 + h * p23
    b13 = p13 + h * p33
    b14 = p14 + h * p34
    s1 = p11 + p14  # theta = m + b: F's b column equals its m column
    s2 = p12 + p24
    s3 = p13 + p34
    s4 = p14 + p44
    b21 = f21 * s1 + f22 * p12 + f23 * p13
    b22 = f21 * s2 + f22 * p22 + f23 * p23
    b23 = f21 * s3 + f22 * p23 + f23 * p33
    b24 = f21 * s4 + f22 * p24 + f23 * p34
    b31 = f31 * s1 + f32 * p12 + f33 * p13
    b32 = f31 * s2 + f32 * p22 + f33 * p23
    b33 = f31 * s3 + f32 * p23 + f33 * p33
    b34 = f31 * s4 + f32 * p24 + f33 * p34
    # P_k|k-1 = B F_k^T + Q, upper triangle.
    return (b00 + h * b02 + q0,
            b01 + h * b03,
            f21 * (b01 + b04) + f22 * b02 + f23 * b03,
            f31 * (b01 + b04) + f32 * b02 + f33 * b03,
            b04,
            b11 + h * b13 + q1,
            f21 * (b11 + b14) + f22 * b12 + f23 * b13,
            f31 * (b11 + b14) + f32 * b12 + f33 * b13,
            b14,
            f21 * (b21 + b24) + f22 * b22 + f23 * b23 + q2,
            f31 * (b21 + b24) + f32 * b22 + f33 * b23,
            b24,
            f31 * (b31 + b34) + f32 * b32 + f33 * b33 + q3,
            b34,
            p44 + q4)


def correct(s: list[float], pc: Packed, y_x: float, y_theta: float, r_x: float,
            r_t: float, offset_fixed: bool = False
            ) -> tuple[list[float], Packed, float, float, float, float]:
    """Measurement update (5.10)-(5.14) with H = [I_2 0] (5.18) and R = diag(r_x, r_t).

    Returns the corrected state, P_k|k, the innovation (5.11) (theta's
    wrapped to (-pi, pi], so a 2 pi jump of the measured angle is not taken
    for motion) and the innovation variances (H P H^T + R)_ii. S = H P H^T + R
    is the upper-left 2x2 block of P plus R, K = P H^T S^-1 (5.12) uses P's
    first two columns, and the Joseph form (5.14)
    P = (I - K H) P (I - K H)^T + K R K^T is evaluated entry by entry as
    C = (I - K H) P, then C (I - K H)^T + K R K^T (upper triangle).
    """
    nu_x = y_x - s[0]
    nu_t = y_theta - s[1]
    if not -math.pi < nu_t <= math.pi:
        nu_t = wrap_angle(nu_t)
    p00, p01, p02, p03, p04, p11, p12, p13, p14, p22, p23, p24, p33, p34, p44 = pc
    # S = H P H^T + R and its inverse in closed form.
    s00 = p00 + r_x
    s11 = p11 + r_t
    det = s00 * s11 - p01 * p01
    i00 = s11 / det
    i01 = -p01 / det
    i11 = s00 / det
    # K = P H^T S^-1 (5.12).
    k00 = p00 * i00 + p01 * i01
    k01 = p00 * i01 + p01 * i11
    k10 = p01 * i00 + p11 * i01
    k11 = p01 * i01 + p11 * i11
    k20 = p02 * i00 + p12 * i01
    k21 = p02 * i01 + p12 * i11
    k30 = p03 * i00 + p13 * i01
    k31 = p03 * i01 + p13 * i11
    if offset_fixed:  # b a considered state (Schmidt): kept, its covariance still exact
        k40 = k41 = 0.0
    else:
        k40 = p04 * i00 + p14 * i01
        k41 = p04 * i01 + p14 * i11
    # x_k|k = x_k|k-1 + K y~ (5.13).
    state = [s[0] + k00 * nu_x + k01 * nu_t, s[1] + k10 * nu_x + k11 * nu_t,
             s[2] + k20 * nu_x + k21 * nu_t, s[3] + k30 * nu_x + k31 * nu_t,
             s[4] + k40 * nu_x + k41 * nu_t]
    # Joseph form (5.14). A = I - K H; C = A P (the entries needed).
    a00 = 1.0 - k00
    a11 = 1.0 - k11
    c00 = a00 * p00 - k01 * p01
    c01 = a00 * p01 - k01 * p11
    c02 = a00 * p02 - k01 * p12
    c03 = a00 * p03 - k01 * p13
    c04 = a00 * p04 - k01 * p14
    c10 = a11 * p01 - k10 * p00
    c11 = a11 * p11 - k10 * p01
    c12 = a11 * p12 - k10 * p02
    c13 = a11 * p13 - k10 * p03
    c14 = a11 * p14 - k10 * p04
    p0 = (p00, p01, p02, p03, p04)
    p1 = (p01, p11, p12, p13, p14)
    c20, c21, c22, c23, c24 = _minus_k_h(k20, k21, p0, p1, (p02, p12, p22, p23, p24))
    c30, c31, _, c33, c34 = _minus_k_h(k30, k31, p0, p1, (p03, p13, p23, p33, p34))
    c40, c41, _, _, c44 = _minus_k_h(k40, k41, p0, p1, (p04, p14, p24, p34, p44))
    # K R K^T with R = diag(r_x, r_theta): (K R)_i0 k_j0 + (K R)_i1 k_j1.
    kr00, kr01 = k00 * r_x, k01 * r_t
    kr10, kr11 = k10 * r_x, k11 * r_t
    kr20, kr21 = k20 * r_x, k21 * r_t
    kr30, kr31 = k30 * r_x, k31 * r_t
    kr40, kr41 = k40 * r_x, k41 * r_t
    packed = (a00 * c00 - k01 * c01 + (kr00 * k00 + kr01 * k01),
              a11 * c01 - k10 * c00 + (kr00 * k10 + kr01 * k11),
              -k20 * c00 - k21 * c01 + c02 + (kr00 * k20 + kr01 * k21),
              -k30 * c00 - k31 * c01 + c03 + (kr00 * k30 + kr01 * k31),
              -k40 * c00 - k41 * c01 + c04 + (kr00 * k40 + kr01 * k41),
              a11 * c11 - k10 * c10 + (kr10 * k10 + kr11 * k11),
              -k20 * c10 - k21 * c11 + c12 + (kr10 * k20 + kr11 * k21),
              -k30 * c10 - k31 * c11 + c13 + (kr10 * k30 + kr11 * k31),
              -k40 * c10 - k41 * c11 + c14 + (kr10 * k40 + kr11 * k41),
              -k20 * c20 - k21 * c21 + c22 + (kr20 * k20 + kr21 * k21),
              -k30 * c20 - k31 * c21 + c23 + (kr20 * k30 + kr21 * k31),
              -k40 * c20 - k41 * c21 + c24 + (kr20 * k40 + kr21 * k41),
              -k30 * c30 - k31 * c31 + c33 + (kr30 * k30 + kr31 * k31),
              -k40 * c30 - k41 * c31 + c34 + (kr30 * k40 + kr31 * k41),
              -k40 * c40 - k41 * c41 + c44 + (kr40 * k40 + kr41 * k41))
    return state, packed, nu_x, nu_t, s00, s11


def _minus_k_h(k0: float, k1: float, p0: tuple[float, ...], p1: tuple[float, ...],
               p_row: tuple[float, ...]) -> tuple[float, ...]:
    """Row i >= 2 of C = (I - K H) P in :func:`correct`: ``P_ij - K_i0 P_0j - K_i1 P_1j``.

    ``k0, k1`` are K's row i, ``p0, p1`` P's rows 0 and 1, ``p_row`` P's row i.
    """
    a0, a1, a2, a3, a4 = p0
    b0, b1, b2, b3, b4 = p1
    c0, c1, c2, c3, c4 = p_row
    return (-k0 * a0 - k1 * b0 + c0, -k0 * a1 - k1 * b1 + c1, -k0 * a2 - k1 * b2 + c2,
            -k0 * a3 - k1 * b3 + c3, -k0 * a4 - k1 * b4 + c4)
