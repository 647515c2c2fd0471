"""Regenerate the angle-of-attack tables of aircraft/fwuav/fwuav.xml.

The lift, drag and pitching-moment tables follow Beard & McLain's stall model
(Small Unmanned Aircraft, Princeton University Press, 2012, eqs. 4.9-4.11):
a sigmoid blend between the attached-flow linear lift and flat-plate lift,
so the coefficients stay bounded over the whole circle of angles of attack.

    python tools/make_fwuav_tables.py      # prints the three <table> blocks

Paste the output over the tables in the XML when a constant below changes.
"""
from __future__ import annotations

import math

# Constants (see the XML header for their sources).
CL0, CL_ALPHA = 0.23, 5.61          # lift at zero alpha, lift-curve slope /rad
CD0, OSWALD, ASPECT = 0.035, 0.80, 2.4**2 / 0.35
CM0, CM_ALPHA = 0.06, -0.84         # 15 % MAC static margin
STALL_ALPHA, BLEND_M = 0.24, 40.0   # sigmoid centre (rad) and steepness


def sigma(a: float) -> float:
    e1 = math.exp(-BLEND_M * (a - STALL_ALPHA))
    e2 = math.exp(BLEND_M * (a + STALL_ALPHA))
    return (1.0 + e1 + e2) / ((1.0 + e1) * (1.0 + e2))


def coefficients(a: float) -> tuple[float, float, float]:
    s = sigma(a)
    cl_lin = CL0 + CL_ALPHA * a
    cl_plate = 2.0 * math.copysign(1.0, a) * math.sin(a) ** 2 * math.cos(a)
    cl = (1 - s) * cl_lin + s * cl_plate
    k = 1.0 / (math.pi * OSWALD * ASPECT)
    cd = (1 - s) * (CD0 + k * cl_lin**2) + s * (CD0 + 2.0 * math.sin(a) ** 2)
    cm = CM0 + CM_ALPHA * math.sin(a)
    return cl, cd, cm


def grid() -> list[float]:
    degs = list(range(-180, -30, 10)) + list(range(-30, 31, 1)) + list(range(40, 181, 10))
    return [math.radians(d) for d in degs]


def table(name: str, col: int) -> str:
    rows = "\n".join(f"          {a: .5f}  {coefficients(a)[col]: .5f}" for a in grid())
    return (f'      <table name="{name}">\n'
            '        <independentVar lookup="row">aero/alpha-rad</independentVar>\n'
            f"        <tableData>\n{rows}\n        </tableData>\n      </table>")


def _main() -> None:
    for name, col in (("aero/CL-alpha", 0), ("aero/CD-alpha", 1), ("aero/Cm-alpha", 2)):
        print(table(name, col))


# --- propulsion: quasi-static electric motor + fixed-pitch propeller --------
# 15x10 in thin-electric propeller: CT(J), CP(J) shaped on the UIUC Propeller
# Data Site's curves for APC thin-electric propellers of this size; negative
# beyond J = 1.15 (a windmilling propeller drags). Motor: 500 W shaft power.
PROP_D_M = 15 * 0.0254
MOTOR_W = 500.0
RHO0 = 1.225
_J = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.1, 1.2, 1.3, 1.5, 1.7, 2.2, 3.0]
_CT = [0.120, 0.115, 0.100, 0.080, 0.055, 0.025, 0.008, -0.010, -0.026, -0.055, -0.085, -0.150, -0.200]
_CP = [0.065, 0.064, 0.062, 0.057, 0.048, 0.033, 0.022, 0.010, -0.002, -0.030, -0.055, -0.100, -0.150]


def _interp(x: float, xs: list[float], ys: list[float]) -> float:
    if x <= xs[0]:
        return ys[0]
    for i in range(1, len(xs)):
        if x <= xs[i]:
            w = (x - xs[i - 1]) / (xs[i] - xs[i - 1])
            return ys[i - 1] + w * (ys[i] - ys[i - 1])
    return ys[-1]


def thrust_n(v_m_s: float, throttle: float) -> float:
    """Steady thrust at sea-level density: the propeller speed n solves
    CP(J) rho n^3 D^5 = throttle * P_max with J = V / (n D) (bisection)."""
    power = throttle * MOTOR_W
    lo, hi = 1e-3, 400.0  # rev/s
    for _ in range(200):
        n = 0.5 * (lo + hi)
        p_req = _interp(v_m_s / (n * PROP_D_M), _J, _CP) * RHO0 * n**3 * PROP_D_M**5
        lo, hi = (n, hi) if p_req < power else (lo, n)
    n = 0.5 * (lo + hi)
    return _interp(v_m_s / (n * PROP_D_M), _J, _CT) * RHO0 * n**2 * PROP_D_M**4


def thrust_table() -> str:
    speeds = [0, 5, 10, 15, 20, 25, 30, 35, 40, 50, 60, 80, 100]
    throttles = [0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    head = "            " + "".join(f"{t:9.2f}" for t in throttles)
    # rows: true airspeed in ft/s (JSBSim's unit), thrust in newtons
    rows = "\n".join(f"          {v / 0.3048:7.2f}" + "".join(f"{thrust_n(v, t):9.3f}" for t in throttles)
                      for v in speeds)
    return ('        <table name="propulsion/thrust-sl-n">\n'
            '          <independentVar lookup="row">velocities/vt-fps</independentVar>\n'
            '          <independentVar lookup="column">fcs/motor-throttle-norm</independentVar>\n'
            f"          <tableData>\n{head}\n{rows}\n          </tableData>\n        </table>")
    print(thrust_table())


if __name__ == "__main__":
    _main()
