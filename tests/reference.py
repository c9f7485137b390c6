"""An independent, deliberately plain per-step implementation of the paper's model.

One Python loop over steps, the equations as printed (with PAPER-NOTES' discretisation),
no numpy tricks: the yardstick the fast code is tested against.
"""

RHO = 1.225
G = 9.81


def reference_wheel_energy_j(t, v, h, m, cda, cr, mode, eta=1.0, cr0=0.004):
    """E_DC [J] summed step by step. mode: 'paper' (eq. 24), 'no-credit', or 'ev' (eq. 27-29)."""
    total = 0.0
    for i in range(len(t) - 1):
        dt = t[i + 1] - t[i]
        k = 0.5 * (v[i + 1] ** 2 - v[i] ** 2)
        a = 0.25 * RHO * (v[i] ** 3 + v[i + 1] ** 3) * dt
        r = 0.5 * G * (v[i] + v[i + 1]) * dt
        e = G * (h[i + 1] - h[i]) if h is not None else 0.0
        delta = m * (k + e) + cda * a + cr * m * r
        if k + e + cr0 * r > 0:  # simplified step (criterion 8)
            total += delta
        elif mode == "paper":
            total += delta
        elif mode == "no-credit":
            if delta > 0:
                total += delta
        elif mode == "ev":
            if delta > 0:
                total += delta
            else:
                total += eta * eta * delta
        else:
            raise ValueError(mode)
    return total
