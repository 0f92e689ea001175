"""A smooth spot model fitted to a beam image by robust least squares: an elliptical
super-Gaussian on a smooth (quadratic) background, whose centre is the beam centroid.

Model, for pixel (x, y) (x = column, y = row, px; intensities in image units):

    I(x, y) = b(x, y) + A exp(-q^P / 2)                                                (1)
    b(x, y) = a + b_x X + b_y Y + c_xx X^2 + c_yy Y^2 + c_xy X Y,  X = x - x_g, Y = y - y_g
    q = (u / s_u)^2 + (v / s_v)^2,
    u =  (x - x0) cos t + (y - y0) sin t,    v = -(x - x0) sin t + (y - y0) cos t

with (x_g, y_g) the initial guess of the centre (it only decorrelates the terms of the
background surface b, a quadratic so that vignetting across the neighbourhood fits), A the
amplitude, s_u >= s_v the widths along and across the major axis at angle t (from +x towards
+y), and P the shape exponent (P = 1 Gaussian, P > 1 flat-topped, P < 1 cuspy). The spot term is
point-symmetric about (x0, y0), so its energy centroid is (x0, y0) exactly, whatever P; the
centroid therefore does not depend on a threshold, and a faint flat-topped spot is centred by
its whole outline instead of by a noise-shaped half-peak region.

Why robust: on a daylight photo of a sunlit target, the residuals of (1) are not Gaussian —
grid lines, fiducials, glints, facet texture and shadow edges. The Cauchy loss
rho(z) = ln(1 + z^2) on z = residual / (f_scale * noise) gives those pixels a bounded influence
(Hampel et al., Robust Statistics, 1986, Sec. 2.3), so they do not drag the centre.

Conventions: (rows, cols) arrays; angles in radians inside, degrees at the edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.errors import InputError
from controller.imaging.background import Background

# Residuals of the fit: about this many pixels (a 13-parameter model; more only costs time).
_FIT_SAMPLES = 12_000
# Cauchy scale in units of the background noise: residuals beyond ~2 noise sigma lose weight
# (near 2.385, the constant of 95 % efficiency for Gaussian noise; Holland & Welsch 1977).
F_SCALE = 2.0
# A fitted spot whose amplitude is below this many residual sigmas is refused as noise.
MIN_SNR = 5.0


@dataclass(frozen=True)
class SpotGuess:
    """Starting point of :func:`fit_spot`: centre (px), peak above the background, widths
    (1-sigma, px) along and across the major axis, and its angle (degrees from +x towards +y)."""

    x: float
    y: float
    peak: float
    sigma_major_px: float
    sigma_minor_px: float
    angle_deg: float


@dataclass(frozen=True)
class SpotFit:
    """Result of :func:`fit_spot` (Eq. 1): centre ``x``, ``y`` (px), ``amplitude`` A,
    ``sigma_major_px``/``sigma_minor_px`` (s_u, s_v), ``angle_deg`` (t), ``exponent`` (P), the
    fitted ``background`` surface, ``residual_rms`` (robust scale of the
    residuals, 1.4826 MAD, image units) and ``pixels`` (residuals used)."""

    x: float
    y: float
    amplitude: float
    sigma_major_px: float
    sigma_minor_px: float
    angle_deg: float
    exponent: float
    background: Background  # the fitted surface b(x, y) of Eq. (1) as a full-frame image
    residual_rms: float
    pixels: int

    def as_dict(self) -> dict:
        return {"centre_px": [self.x, self.y], "amplitude": self.amplitude,
                "sigma_major_px": self.sigma_major_px, "sigma_minor_px": self.sigma_minor_px,
                "angle_deg": self.angle_deg, "exponent": self.exponent,
                "residual_rms": self.residual_rms}


# The shape exponent P is kept in [0.5, 4] (cusp to near box): beyond, Eq. (1) stops being a spot
# (a box edge can lock onto a shadow step; a needle onto a glint).
P_MIN, P_MAX = 0.5, 4.0


def _exponent(k: float) -> tuple[float, float]:
    """P = P_MIN + (P_MAX - P_MIN) / (1 + e^-k) and dP/dk; k = 0 is P = 2.25, so the start
    k0 = logit((1 - P_MIN) / (P_MAX - P_MIN)) gives a Gaussian (P = 1)."""
    sig = 0.5 * (1.0 + np.tanh(0.5 * k))  # = 1 / (1 + e^-k), without overflow for large |k|
    return P_MIN + (P_MAX - P_MIN) * sig, (P_MAX - P_MIN) * sig * (1.0 - sig)


_K_GAUSSIAN = float(np.log((1.0 - P_MIN) / (P_MAX - 1.0)))


def _model(p: np.ndarray, x: np.ndarray, y: np.ndarray, xg: float, yg: float,
           jacobian: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Eq. (1) at the pixels (x, y); p = (a, b_x, b_y, A, x0, y0, ln s_u, ln s_v, t, k, c_xx,
    c_yy, c_xy) with P = :func:`_exponent` (k).
    With ``jacobian``, also d model / d p, shape (n, 13), by the chain rule through q:
    dq/dx0 = -2 (U cos t / s_u - V sin t / s_v), dq/dy0 = -2 (U sin t / s_u + V cos t / s_v),
    dq/d ln s_u = -2 U^2, dq/d ln s_v = -2 V^2, dq/dt = 2 U V (s_v / s_u - s_u / s_v), with
    U = u / s_u, V = v / s_v; and d exp(-q^P/2) / dq = -P q^(P-1) exp(-q^P/2) / 2."""
    a, bx, by, amp, x0, y0, lu, lv, t, k, cxx, cyy, cxy = p
    c, s = np.cos(t), np.sin(t)
    su, sv = np.exp(lu), np.exp(lv)
    power, dpower = _exponent(k)
    dx, dy = x - x0, y - y0
    uu, vv = (dx * c + dy * s) / su, (dy * c - dx * s) / sv
    # q = 0 only at the centre pixel; the floor keeps q^(P-1) and ln q finite there.
    q = np.maximum(uu * uu + vv * vv, 1e-12)
    lnq = np.log(q)
    # q^P capped at e^50, where exp(-q^P / 2) is 0 to double precision: no overflow far out.
    qp = np.exp(np.minimum(power * lnq, 50.0))
    e = np.exp(-0.5 * qp)
    ex, ey = x - xg, y - yg
    model = a + bx * ex + by * ey + cxx * ex * ex + cyy * ey * ey + cxy * ex * ey + amp * e
    if not jacobian:
        return model
    g = -0.5 * amp * e * power * qp / q  # d(A e)/dq
    jac = np.empty((x.size, 13))
    jac[:, 0] = 1.0
    jac[:, 1] = x - xg
    jac[:, 2] = y - yg
    jac[:, 3] = e
    jac[:, 4] = g * -2.0 * (uu * c / su - vv * s / sv)
    jac[:, 5] = g * -2.0 * (uu * s / su + vv * c / sv)
    jac[:, 6] = g * -2.0 * uu * uu
    jac[:, 7] = g * -2.0 * vv * vv
    jac[:, 8] = g * 2.0 * uu * vv * (sv / su - su / sv)
    jac[:, 9] = -0.5 * amp * e * qp * lnq * dpower
    jac[:, 10] = ex * ex
    jac[:, 11] = ey * ey
    jac[:, 12] = ex * ey
    return model, jac


def _robust_lm(model_jac, v: np.ndarray, p0: np.ndarray, scale: float, max_iter: int = 100,
               tol: float = 1e-9) -> tuple[np.ndarray, bool, np.ndarray]:
    """Minimise sum rho(r_i / scale), rho(z) = ln(1 + z^2) (Cauchy), r = model(p) - v, by
    Levenberg-Marquardt on iteratively reweighted least squares: with weights
    w_i = 1 / (1 + (r_i / scale)^2) (= rho'(z) / 2z), solve
    (J^T W J + lam diag(J^T W J)) dp = -J^T W r, accept dp if the robust cost falls (lam / 3),
    else raise lam x 4 (Marquardt 1963; IRLS: Holland & Welsch 1977). Returns (p, converged,
    residuals). The small normal equations keep the cost at a few passes over the pixels."""
    p = p0.astype(np.float64)

    def cost(r):
        return float(np.sum(np.log1p((r / scale) ** 2)))

    m, jac = model_jac(p)
    r = m - v
    c = cost(r)
    lam = 1e-3
    for _ in range(max_iter):
        w = 1.0 / (1.0 + (r / scale) ** 2)
        jw = jac * w[:, None]
        a = jw.T @ jac
        g = jw.T @ r
        while True:
            try:
                dp = np.linalg.solve(a + lam * np.diag(np.diag(a)) + 1e-12 * np.eye(p.size), -g)
            except np.linalg.LinAlgError:
                return p, False, r
            m_new, jac_new = model_jac(p + dp)
            r_new = m_new - v
            c_new = cost(r_new) if np.all(np.isfinite(r_new)) else np.inf
            if c_new <= c:
                break
            lam *= 4.0
            if lam > 1e12:
                return p, True, r  # no step lowers the cost: at the minimum to rounding
        p, r, jac = p + dp, r_new, jac_new
        done = c - c_new <= tol * max(c, 1e-300)
        c, lam = c_new, max(lam / 3.0, 1e-12)
        if done:
            return p, True, r
    return p, False, r


def fit_spot(image: np.ndarray, region: np.ndarray, guess: SpotGuess, background: Background,
             f_scale: float = F_SCALE) -> SpotFit:
    """Fit Eq. (1) to ``image`` over the bool ``region`` (rows, cols) by robust least squares.

    ``region`` should hold the spot and a ring of background around it (e.g. the neighbourhood
    of :func:`controller.imaging.background.estimate_local_background`); it is subsampled on a
    regular grid to about 12,000 pixels. ``background`` (a plane) starts the linear terms and
    sets the loss scale (``f_scale`` x its ``noise``); the curvature terms start at 0.
    Cauchy-loss Levenberg-Marquardt (:func:`_robust_lm`) with the analytic Jacobian of Eq. (1).

    Raises InputError when the fit does not converge or ends with a non-finite, off-region,
    unresolved (a width below 1 px) or insignificant spot (amplitude <= 5 residual sigmas), so
    that a caller never gets a centre the model does not support.
    """
    img = np.asarray(image)
    reg = np.asarray(region, bool)
    n_region = int(np.count_nonzero(reg))
    if n_region < 20:
        raise InputError(f"spot fit: only {n_region} pixels around the spot")
    step = max(1, int(np.sqrt(n_region / _FIT_SAMPLES)))
    ys, xs = np.nonzero(reg[::step, ::step])
    ys, xs = ys * step, xs * step
    v = img[ys, xs].astype(np.float64)
    x, y = xs.astype(np.float64), ys.astype(np.float64)
    xg, yg = guess.x, guess.y
    a0 = background.level + background.slope_x * xg + background.slope_y * yg
    p0 = np.array([a0, background.slope_x, background.slope_y, guess.peak, xg, yg,
                   np.log(max(guess.sigma_major_px, 1.0)), np.log(max(guess.sigma_minor_px, 1.0)),
                   np.radians(guess.angle_deg), _K_GAUSSIAN, 0.0, 0.0, 0.0])
    scale = f_scale * max(background.noise, 1e-6 * max(abs(guess.peak), 1e-12))
    p, converged, resid = _robust_lm(lambda q: _model(q, x, y, xg, yg, jacobian=True), v, p0, scale)
    a, bx, by, amp, x0, y0, lu, lv, t, k = p[:10]
    inside = 0 <= int(round(y0)) < reg.shape[0] and 0 <= int(round(x0)) < reg.shape[1] \
        and reg[int(round(y0)), int(round(x0))]
    su, sv = float(np.exp(lu)), float(np.exp(lv))
    rms = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    # A spot must be resolved (both widths >= 1 px) and stand out of the noise (peak above
    # MIN_SNR residual sigmas); a fit to noise ends as a faint needle.
    if (not converged or not np.all(np.isfinite(p)) or not inside or not amp > MIN_SNR * rms
            or min(su, sv) < 1.0):
        raise InputError(f"spot fit failed ({'converged' if converged else 'no convergence'}; centre "
                         f"({x0:.1f}, {y0:.1f}) px, amplitude {amp:.3g} over residual noise {rms:.3g}, "
                         f"widths {su:.2g} x {sv:.2g} px)")
    if sv > su:  # report the major axis first
        su, sv, t = sv, su, t + 0.5 * np.pi
    angle = float(np.degrees(np.arctan2(np.sin(2 * t), np.cos(2 * t)) / 2))  # axis: mod 180 -> (-90, 90]
    if angle <= -90.0:
        angle += 180.0
    ey, ex = np.mgrid[0:reg.shape[0], 0:reg.shape[1]].astype(np.float64)
    ex -= xg
    ey -= yg
    cxx, cyy, cxy = p[10:]
    surface = a + bx * ex + by * ey + cxx * ex * ex + cyy * ey * ey + cxy * ex * ey
    fitted = Background(level=float(a), noise=rms, image=surface)
    return SpotFit(x=float(x0), y=float(y0), amplitude=float(amp), sigma_major_px=su, sigma_minor_px=sv,
                   angle_deg=angle, exponent=float(_exponent(k)[0]), background=fitted, residual_rms=rms,
                   pixels=int(v.size))
