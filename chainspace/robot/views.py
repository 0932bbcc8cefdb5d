"""How a sequence sees the robot's base frame: a similarity onto 3D points or weak-perspective
cameras onto 2D tracks (:class:`_View`), and their closed-form starts.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import numpy as np



def similarity_align(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None, *,
                     reflection: bool = False, scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama's weighted similarity ``dst ~ s R src + t`` over all points (..., 3); NaN rows ignored.

    Returns (s, R (3, 3), t (3,)). ``reflection=False`` keeps det(R) = +1; ``scale=False`` fixes s = 1
    (a rigid motion).
    """
    a = src.reshape(-1, 3)
    b = dst.reshape(-1, 3)
    w = np.ones(len(a)) if weights is None else np.asarray(weights, float).reshape(-1).copy()
    ok = np.isfinite(a).all(1) & np.isfinite(b).all(1) & (w > 0)
    a, b, w = a[ok], b[ok], w[ok] / w[ok].sum()
    ma, mb = w @ a, w @ b
    A, B = a - ma, b - mb
    cov = (B * w[:, None]).T @ A
    U, S, Vt = np.linalg.svd(cov)
    d = np.ones(3)
    if not reflection and np.linalg.det(U @ Vt) < 0:
        d[-1] = -1
    R = U @ np.diag(d) @ Vt
    var = float(w @ (A ** 2).sum(1))
    s = float((S * d).sum() / var) if var > 0 and scale else 1.0
    return s, R, mb - s * R @ ma


def turn_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (degrees) of the rotation between rotations a and b (3, 3)."""
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0))))


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices (entries written in place: nested np.stack
    cost more than the products the solvers make with them)."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -w, y, -x
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = w, -y, x
    return out


def _rotvec(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) (Rodrigues)."""
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = _skew(w)
    small = th < 1e-8
    a = np.where(small, 1.0, np.sin(th) / np.where(small, 1.0, th))
    b = np.where(small, 0.5, (1 - np.cos(th)) / np.where(small, 1.0, th ** 2))
    return np.eye(3) + a * K + b * K @ K


def _affine_camera(x: np.ndarray, u: np.ndarray, w: np.ndarray, per_frame: bool) -> tuple[np.ndarray, np.ndarray]:
    """Weak-perspective camera(s) s R[:2] (F, 2, 3) and t (F, 2) closest to u ~ M x + t (least squares,
    then the 2x3 matrix projected onto scaled orthonormal rows)."""
    F = len(x)
    groups = [np.arange(F)[i:i + 1] for i in range(F)] if per_frame else [np.arange(F)]
    cams, ts = np.zeros((F, 2, 3)), np.zeros((F, 2))
    for g in groups:
        xs, us, ws = x[g].reshape(-1, 3), u[g].reshape(-1, 2), w[g].reshape(-1)
        ok = (ws > 0) & np.isfinite(us).all(1)
        A = np.hstack([xs[ok], np.ones((ok.sum(), 1))]) * np.sqrt(ws[ok])[:, None]
        sol = np.linalg.lstsq(A, us[ok] * np.sqrt(ws[ok])[:, None], rcond=None)[0]  # (4, 2)
        M = sol[:3].T
        U, S, Vt = np.linalg.svd(M, full_matrices=False)
        cams[g] = S.mean() * (U @ Vt)
        ts[g] = sol[3]
    return cams, ts


def _camera_view(x: np.ndarray, u: np.ndarray, w: np.ndarray, per_frame: bool) -> _View:
    """The weak-perspective camera(s) closest to u ~ P x + t, as a view for the solvers."""
    F = len(x)
    P0, t20 = _affine_camera(x, u, w, per_frame)
    views = [_camera_to_rotation(P) for P in (P0 if per_frame else P0[:1])]
    return _View(np.array([v[0] for v in views]), np.array([v[1] for v in views]),
                 t20 if per_frame else t20[:1], np.arange(F) if per_frame else np.zeros(F, int))


def _camera_to_rotation(M: np.ndarray) -> tuple[float, np.ndarray]:
    """A weak-perspective 2x3 camera s R[:2] -> (s, full rotation R)."""
    s = float(np.linalg.norm(M, axis=1).mean())
    r1, r2 = M[0] / np.linalg.norm(M[0]), M[1] / np.linalg.norm(M[1])
    r2 = r2 - (r1 @ r2) * r1
    r2 /= np.linalg.norm(r2)
    return s, np.stack([r1, r2, np.cross(r1, r2)])


@dataclass
class _View:
    """The sequence's view of the robot's base frame: ``target ~ S[c] (R[c] x)[:D] + T[c]`` for the view
    c = cam_of[f] of frame f. D = 3: a similarity onto 3D points; D = 2: weak-perspective cameras."""

    S: np.ndarray  # (C,) scale
    R: np.ndarray  # (C, 3, 3) rotation
    T: np.ndarray  # (C, D) translation
    cam_of: np.ndarray  # (F,) view index of each frame

    @staticmethod
    def identity(n_frames: int) -> _View:
        """One view that leaves base-frame points as they are (3D targets in the base frame)."""
        return _View(np.ones(1), np.eye(3)[None], np.zeros((1, 3)), np.zeros(n_frames, int))

    @property
    def per_frame(self) -> bool:
        return len(self.S) == len(self.cam_of) and len(self.S) > 1

    def apply(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(prediction (F, J, D), rotated points y = R x (F, J, 3))."""
        c = self.cam_of
        # one view for all frames: its rotation as one operand, not gathered once per frame
        y = np.einsum("ij,fkj->fki", self.R[0], x) if len(self.S) == 1 else np.einsum("fij,fkj->fki", self.R[c], x)
        D = self.T.shape[1]
        return self.S[c][:, None, None] * y[..., :D] + self.T[c][:, None], y

    def moved(self, dc: np.ndarray) -> _View:
        """The view after a step dc (C, 3 + 1 + D): rotation vector (R <- exp(w^) R), scale, translation."""
        return _View(self.S + dc[:, 3], np.einsum("cij,cjk->cik", _rotvec(dc[:, :3]), self.R),
                     self.T + dc[:, 4:], self.cam_of)

    def take(self, idx: np.ndarray) -> _View:
        """The view of frames idx only."""
        if self.per_frame:
            return _View(self.S[idx], self.R[idx], self.T[idx], np.arange(len(idx)))
        return _View(self.S, self.R, self.T, self.cam_of[idx])

    def put(self, idx: np.ndarray, sub: _View, accept: np.ndarray) -> _View:
        """This view with the frames idx[accept] taken from sub (a view from take(idx))."""
        if not accept.any():
            return self
        if not self.per_frame:
            return _View(sub.S, sub.R, sub.T, self.cam_of)
        S, R, T = self.S.copy(), self.R.copy(), self.T.copy()
        S[idx[accept]], R[idx[accept]], T[idx[accept]] = sub.S[accept], sub.R[accept], sub.T[accept]
        return _View(S, R, T, self.cam_of)

    def matrices(self) -> np.ndarray:
        """(F, D, 3) the linear part s R[:D] per frame."""
        c = self.cam_of
        return self.S[c][:, None, None] * self.R[c][:, : self.T.shape[1]]

    @property
    def n_params(self) -> int:
        """Parameters of one view in a step of :meth:`moved`: rotation vector, scale, translation."""
        return 4 + self.T.shape[1]

    def derivatives(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Jacobian blocks of the prediction at y = R x (from :meth:`apply`): d prediction / d point
        (F, J, D, 3) and d prediction / d view parameters (F, J, D, n_params) (the step of :meth:`moved`)."""
        F, J = y.shape[:2]
        D = self.T.shape[1]
        sc = self.S[self.cam_of][:, None, None, None]
        dx = np.broadcast_to(self.matrices()[:, None], (F, J, D, 3))
        dc = np.concatenate([-sc * _skew(y)[..., :D, :], y[..., :D, None],
                             np.broadcast_to(np.eye(D), (F, J, D, D))], -1)
        return dx, dc


def _align(x: np.ndarray, X: np.ndarray, w: np.ndarray, transform: str) -> _View:
    """The sequence's similarity (or rigid motion, or identity) from base-frame points x onto X."""
    if transform == "none":
        s, R, t = 1.0, np.eye(3), np.zeros(3)
    else:
        s, R, t = similarity_align(np.broadcast_to(x, X.shape), X, w)
        s = s if transform == "similarity" else 1.0
    return _View(np.array([s]), R[None], t[None], np.zeros(len(X), int))


def _looks_down(view: _View) -> float:
    """How much the camera(s) look down on the base plane: minus the z of the forward axis (the
    rotation's third row, image y pointing down), averaged; > 0 from above."""
    return -float(np.mean(view.R[:, 2, 2]))


def _pinhole_pixels(f: float, c: np.ndarray | float, y: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) of camera-frame points y (..., 3) in metres: f (y_x, y_y) / y_z + c (a depth
    within a nanometre of 0 is held there: the solvers' steps stay finite)."""
    z = np.where(np.abs(y[..., 2:]) > 1e-9, y[..., 2:], 1e-9)
    return f * y[..., :2] / z + c


def _pinhole_pixels_by_point(f: float, y: np.ndarray) -> np.ndarray:
    """d pixels / d camera-frame point (..., 2, 3), px per metre, at points y (..., 3)."""
    z = np.where(np.abs(y[..., 2]) > 1e-9, y[..., 2], 1e-9)
    a = f / z
    P = np.zeros(y.shape[:-1] + (2, 3))
    P[..., 0, 0] = a
    P[..., 1, 1] = a
    P[..., :, 2] = -a[..., None] * y[..., :2] / z[..., None]
    return P


@dataclass
class _PinholeView:
    """One static pinhole camera: ``u = f (y_x, y_y) / y_z + c`` with ``y = R x + t`` (camera frame,
    metres; x in the robot's base frame). Same interface as :class:`_View` for the solvers; its step
    (:meth:`moved`) is a rotation vector (R <- exp(w^) R), a translation, when ``fit_focal`` the
    change of log f and when ``fit_centre`` the change of the principal point c (px). ``cam_of`` (F,)
    is all zeros (one camera)."""

    R: np.ndarray  # (1, 3, 3)
    t: np.ndarray  # (1, 3)
    f: float
    c: np.ndarray  # (2,) principal point, px
    cam_of: np.ndarray
    fit_focal: bool = False
    fit_centre: bool = False

    per_frame = False

    @property
    def S(self) -> np.ndarray:  # the solvers count views by len(S)
        return np.ones(1)

    @property
    def n_params(self) -> int:
        return 6 + self.fit_focal + 2 * self.fit_centre

    def apply(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(prediction (F, J, 2) px, camera-frame points y = R x + t (F, J, 3))."""
        y = np.einsum("ij,fkj->fki", self.R[0], x) + self.t[0]
        return _pinhole_pixels(self.f, self.c, y), y

    def derivatives(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d prediction / d point (F, J, 2, 3) and / d view parameters (F, J, 2, n_params)."""
        P = _pinhole_pixels_by_point(self.f, y)
        dx = P @ self.R[0]
        dw = P @ -_skew(y - self.t[0])  # d y / d w = -[R x]^
        parts = [dw, P]
        if self.fit_focal:
            parts.append(_pinhole_pixels(self.f, 0.0, y)[..., None])  # d u / d log f
        if self.fit_centre:
            parts.append(np.broadcast_to(np.eye(2), y.shape[:-1] + (2, 2)))  # d u / d c
        return dx, np.concatenate(parts, -1)

    def moved(self, dc: np.ndarray) -> "_PinholeView":
        dc = np.asarray(dc).reshape(-1)
        f = self.f * float(np.exp(dc[6])) if self.fit_focal else self.f
        c = self.c + dc[6 + self.fit_focal:] if self.fit_centre else self.c
        return replace(self, R=_rotvec(dc[:3])[None] @ self.R, t=self.t + dc[3:6], f=f, c=c)

    def take(self, idx: np.ndarray) -> "_PinholeView":
        return replace(self, cam_of=self.cam_of[idx])

    def put(self, idx: np.ndarray, sub: "_PinholeView", accept: np.ndarray) -> "_PinholeView":
        if not accept.any():
            return self
        return replace(sub, cam_of=self.cam_of)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.f, 0.0, self.c[0]], [0.0, self.f, self.c[1]], [0.0, 0.0, 1.0]])

    def weak_approximation(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(F, 2, 3), (F, 2): the weak-perspective camera u ~ P x + t2 that linearises this one at the
        depth of the points x (F, J, 3) (their centroid's, over the sequence)."""
        F = len(self.cam_of)
        zc = float(np.nanmean(np.einsum("j,fkj->fk", self.R[0, 2], x))) + self.t[0, 2]
        s = self.f / zc
        return (np.broadcast_to(s * self.R[0, :2], (F, 2, 3)).copy(),
                np.broadcast_to(self.c + s * self.t[0, :2], (F, 2)).copy())

    def matrices(self) -> np.ndarray:
        return np.broadcast_to(self.R[0, :2], (len(self.cam_of), 2, 3))


def _pinhole_from_weak(view: _View, x: np.ndarray, f: float, c: np.ndarray, fit_focal: bool) -> _PinholeView:
    """The pinhole camera of focal f, principal point c that sees the points x (F, J, 3, base frame) as
    the weak-perspective camera ``view`` (one static) does at their centroid: same rotation, depth
    of the centroid f / s, image position of the base origin from the translation."""
    R = view.R[0]
    s = float(view.S[0])
    zc = float(np.nanmean(np.einsum("j,fkj->fk", R[2], x)))
    tz = f / s - zc
    txy = (view.T[0] - c) / s * (tz + zc) / (f / s)
    return _PinholeView(R[None].copy(), np.concatenate([txy, [tz]])[None], float(f), np.asarray(c, float),
                        view.cam_of.copy(), fit_focal)
