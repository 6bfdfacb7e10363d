"""Contact laws: the slider's velocity change when an impacter pair hits its wall.

Both laws take the impulse along the impacter's axis x, the line of action the
paper's eqs. (8)-(9) imply (no impulsive reaction from the impacter's suspension,
so momentum along the slider axis zeta is conserved); they differ in what the
restitution acts on.  See docs/contact.md for the derivation.

PAPER, eq. (10), as printed: the tip rebounds at -e v- as from a wall that does
not recoil, and the slider takes the momentum the pair loses along zeta,

    dV = s (1 + e) g v-,              g = 2 (m/M) cos(theta).

TWO_BODY: a two-body collision of the pair (mass 2m, moving along x) with the
slider (mass M, moving along zeta), restitution e on their relative velocity
along x, u = v- - s V- cos(theta):

    J  = (1 + e) m_eff u,             1/m_eff = 1/(2m) + cos^2(theta)/M,
    dV = s J cos(theta) / M = s (1 + e) g u / (1 + q),      q = g cos(theta),
    v+ = v- - J / (2m)      = v- - (1 + e) u / (1 + q),

and no impulse (dV = 0) when u <= 0: a slider already receding along x at least
as fast as the tip is not kicked.  As m/M -> 0, q -> 0 and (for V- = 0) dV tends
to eq. (10) with relative difference q / (1 + q).

Units: velocities [m/s], g, q, cos(theta), e and s dimensionless.
"""

from __future__ import annotations

from numba import njit

#: Contact-law codes passed to :func:`model.kernels.slider.run_slider`.
PAPER = 0
TWO_BODY = 1

#: Columns of the per-kick record of the two-body law (a float array, shape (n, N_COLS)).
COL_SPEED = 0      # v- of the impact, or the sum of v- of a chatter tail [m/s]
COL_SIGN = 1       # s: +1 if the pair pushes zeta up, -1 if down
COL_GAIN = 2       # g = 2 (m/M) cos(theta) [-]
COL_COS = 3        # cos(theta) [-]
COL_E = 4          # e [-]
COL_TAIL = 5       # 1.0 for a chatter tail (geometric sequence v-_{k+1} = e v-_k), else 0.0
N_COLS = 6

#: A chatter tail is applied impact by impact until v-_k falls below this fraction
#: of its first term (the remaining sum is then below ~1e-16 of the tail), or
#: TAIL_MAX_IMPACTS impacts: the sequence is geometric, so the cap is never the
#: binding one for e < 0.95.
TAIL_REL = 1e-17
TAIL_MAX_IMPACTS = 1000


@njit(cache=True, nogil=True)
def two_body_impact(V, v, s, g, c, e):
    """One two-body impact of the pair on the slider.

    Parameters
    ----------
    V : float
        Slider velocity V- along zeta just before the impact [m/s].
    v : float
        Tip speed v- along the impacter axis x, towards the wall [m/s].
    s : float
        +1 if the pair pushes zeta up, -1 if down.
    g : float
        2 (m/M) cos(theta), the paper's gain of eq. (10) per (1 + e) [-].
    c : float
        cos(theta) [-], > 0.
    e : float
        Coefficient of restitution [-], in [0, 1].

    Returns
    -------
    dV : float
        Slider velocity change V+ - V- [m/s] (0.0 without approach).
    v_plus : float
        The tip's velocity along x just after, by the same collision [m/s]
        (v- when there is no approach).
    """
    u = v - s * V * c
    if not u > 0.0:
        return 0.0, v
    one_q = 1.0 + g * c
    return s * (1.0 + e) * g * u / one_q, v - (1.0 + e) * u / one_q


@njit(cache=True, nogil=True)
def two_body_kick(V, rec):
    """Slider velocity after the kick (or chatter tail) of one per-kick record [m/s].

    ``rec`` is one row of the per-kick record (columns COL_*).  A chatter tail
    summed in closed form by the impacter kernel (sum S of the sequence
    v-_k = v-_1 e^(k-1)) is applied impact by impact, v-_1 = S (1 - e), each
    with the slider velocity the previous one left: the sequence stops kicking
    as soon as the slider recedes faster than the tip approaches.
    """
    v = rec[COL_SPEED]
    s = rec[COL_SIGN]
    g = rec[COL_GAIN]
    c = rec[COL_COS]
    e = rec[COL_E]
    if rec[COL_TAIL] == 0.0:
        dV, _ = two_body_impact(V, v, s, g, c, e)
        return V + dV
    vk = v * (1.0 - e)
    floor = TAIL_REL * vk
    for _ in range(TAIL_MAX_IMPACTS):
        if not vk > floor:
            break
        dV, _ = two_body_impact(V, vk, s, g, c, e)
        if dV == 0.0:
            # no approach: every later (slower) impact of the tail has none either
            break
        V += dV
        vk *= e
    return V
