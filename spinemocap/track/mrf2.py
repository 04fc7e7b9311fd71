"""MRF2: refine the dots on the camera images (paper Sec. 3.3, Eq. 10-11).

State: 3D position per dot (mm, world), solid edges only. Energy:

- unary (Eq. 10): ``sum_c I_c(Phi_c(x_s))`` over the cameras that see the dot: it projects inside
  the image and its outward normal faces the camera (self-occlusion test; normals from the
  labelled dots' local tape frames unless given);
- pairwise (Eq. 11), ``p = x_s - x_t``, ``x_st`` the midpoint:
  ``theta5 sum_c (I_c(x_s) + I_c(x_t) - 2 I_c(x_st))`` (dots bright, tape between them dark)
  ``+ theta6 <p, n_st>^2 + theta7 <p, alpha_st>^2 + theta8 (|p| - L)^2``. ``alpha_st`` is the
  in-plane direction perpendicular to where the edge should point given the current tape frame
  (for a transverse edge: the longitudinal axis, as in the paper); ``L`` the rest length.

Minimised by the particle BP of :mod:`spinemocap.track.pbp`, optionally followed (beyond the
paper, ``polish``) by a short L-BFGS descent on the same energy with autograd, which moves the
dots continuously into the evidence minima (particles alone stop at their sampling grain).
The energy terms are written once in torch and serve both.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Iterator, Sequence

import numpy as np
import torch

from ..camera import Rig
from ..geometry import distort
from ..tape import TapeGraph
from .config import MRF2Config
from .evidence import EvidenceImage, EvidenceStack
from .pbp import ParticleBP, mrf_energy
from .template import tape_frames
from .types import MRFResult


class _TorchRig:
    """Batched projection of world points (..., 3) mm into C cameras -> (C, ..., 2) px, with
    OpenCV distortion, in torch so it is differentiable."""

    def __init__(self, rig: Rig):
        self.R = torch.tensor(np.stack([c.R for c in rig]), dtype=torch.float64)
        self.t = torch.tensor(np.stack([c.t for c in rig]), dtype=torch.float64)
        self.K = torch.tensor(np.stack([c.K for c in rig]), dtype=torch.float64)
        self.dist = torch.tensor(np.stack([c.dist for c in rig]), dtype=torch.float64)
        self.centers = np.stack([c.center for c in rig])
        self.sizes = [c.size for c in rig]

    def project(self, x: torch.Tensor) -> torch.Tensor:
        u, v = self.project_uv(x)
        return torch.stack([u, v], dim=-1).reshape(u.shape[0], *x.shape[:-1], 2)

    def project_uv(self, x: torch.Tensor, cams: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`project` of the points x (..., 3) flattened, as the pixel columns u and rows v
        (C', N) each (u NaN behind the camera); ``cams``: (C,) bool, into those cameras only (the
        same values)."""
        R, t, K, dist = (self.R, self.t, self.K, self.dist) if cams is None else \
            (self.R[cams], self.t[cams], self.K[cams], self.dist[cams])
        flat = x.reshape(1, -1, 3)
        xc = flat @ R.transpose(1, 2) + t[:, None, :]  # (C, N, 3)
        z = xc[..., 2].clamp(min=1e-6)
        xn, yn = xc[..., 0] / z, xc[..., 1] / z
        k1, k2, p1, p2, k3 = (dist[:, i, None] for i in range(5))
        r2 = xn * xn + yn * yn
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
        yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
        u = K[:, 0, 0, None] * xd + K[:, 0, 1, None] * yd + K[:, 0, 2, None]
        v = K[:, 1, 1, None] * yd + K[:, 1, 2, None]
        behind = xc[..., 2] <= 1e-6
        u = torch.where(behind, torch.full_like(u, float("nan")), u)
        return u, v


class _ImageCosts:
    """The capped image costs of :class:`RefinementMRF` (``_TorchRig.project_uv``, then
    ``EvidenceStack.sample_uv``, then the cap) in numpy, for particle BP's evaluations (no
    gradients): the same IEEE operations in the same order on the points' coordinates as flat
    rows and the cameras' constants as (C, 1) columns, so the same values bit for bit (pinned
    against the torch path in ``tests/track/test_track_fast_paths.py``), without torch's per-operation
    cost, the strided component reads and the per-call camera indexing (a camera subset's
    constants are sliced once and kept). The 3x3 rotation as ``(x r0 + y r1) + z r2``: the
    order in which MKL's batched matmul sums the three products (checked by the same test)."""

    def __init__(self, cams: _TorchRig, stack: EvidenceStack, cap: float | None):
        R, t, K, dist = (a.numpy() for a in (cams.R, cams.t, cams.K, cams.dist))
        flat = stack._flat.numpy()
        self.h, self.w = stack.shape
        w = self.w
        # the four bilinear corners as shifted views of the canvas: flat[idx + 1] is flat1[idx]
        self.flat, self.flat1, self.flatw, self.flatw1 = flat, flat[1:], flat[w:], flat[w + 1:]
        self.cap = cap
        column = {
            "r": [[R[:, i, j, None].copy() for j in range(3)] for i in range(3)],
            "t": [t[:, i, None].copy() for i in range(3)],
            "k1": dist[:, 0, None].copy(), "k2": dist[:, 1, None].copy(), "p1": dist[:, 2, None].copy(),
            "p2": dist[:, 3, None].copy(), "k3": dist[:, 4, None].copy(),
            "two_p1": 2 * dist[:, 2, None], "two_p2": 2 * dist[:, 3, None],
            "fx": K[:, 0, 0, None].copy(), "skew": K[:, 0, 1, None].copy(), "cx": K[:, 0, 2, None].copy(),
            "fy": K[:, 1, 1, None].copy(), "cy": K[:, 1, 2, None].copy(),
            "ox": stack._origin.numpy()[:, 0, 0, None].copy(), "oy": stack._origin.numpy()[:, 0, 1, None].copy(),
            "scale": stack._scale.numpy().copy(), "base": stack._base.numpy().copy(),
        }
        self._all = column
        column["unit_scale"] = bool((column["scale"] == 1.0).all())
        self._subsets: dict[bytes, dict] = {}

    def _constants(self, cams: np.ndarray | None) -> dict:
        if cams is None:
            return self._all
        key = cams.tobytes()
        got = self._subsets.get(key)
        if got is None:
            def pick(v):
                return [pick(a) for a in v] if isinstance(v, list) else v[cams]
            got = {k: pick(v) for k, v in self._all.items() if k != "unit_scale"}
            got["unit_scale"] = bool((got["scale"] == 1.0).all())
            self._subsets[key] = got
        return got

    CHUNK = 1024  # points per pass: the temporaries stay in the cache (and off fresh pages)

    def __call__(self, px: np.ndarray, py: np.ndarray, pz: np.ndarray, cams: np.ndarray | None = None) -> np.ndarray:
        """Costs (C', N) of the points with coordinates ``px``, ``py``, ``pz`` (N,) each, in the
        cameras ``cams`` (int indices, or None: all); in passes of ``CHUNK`` points (element by
        element: the same values)."""
        k = self._constants(cams)
        n = len(px)
        if n <= 2 * self.CHUNK:
            return self._costs(px, py, pz, k)
        out = np.empty((len(k["base"]), n))
        for a in range(0, n, self.CHUNK):
            b = min(a + self.CHUNK, n)
            out[:, a:b] = self._costs(px[a:b], py[a:b], pz[a:b], k)
        return out

    def _costs(self, px: np.ndarray, py: np.ndarray, pz: np.ndarray, k: dict) -> np.ndarray:
        """The costs of one pass. Each line is the torch expression's operations in its order
        (``a * b + c * d + e`` as ``((a b) + (c d)) + e``), written into a few (C', N) buffers
        in place instead of a fresh array per operation (the same values: only where they are
        stored differs; products and sums of two terms are taken in either order, which IEEE
        arithmetic gives bit for bit)."""
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = k["r"]
        t0, t1, t2 = k["t"]
        mul = np.multiply
        tmp = np.empty((len(t0), len(px)))
        # camera coordinates: px * r00 + py * r01 + pz * r02 + t0
        xc0 = mul(px, r00)
        xc0 += mul(py, r01, out=tmp)
        xc0 += mul(pz, r02, out=tmp)
        xc0 += t0
        xc1 = mul(px, r10)
        xc1 += mul(py, r11, out=tmp)
        xc1 += mul(pz, r12, out=tmp)
        xc1 += t1
        xc2 = mul(px, r20)
        xc2 += mul(py, r21, out=tmp)
        xc2 += mul(pz, r22, out=tmp)
        xc2 += t2
        z = np.maximum(xc2, 1e-6)
        xn = np.divide(xc0, z, out=xc0)
        yn = np.divide(xc1, z, out=xc1)
        r2 = mul(xn, xn, out=z)  # xn * xn + yn * yn
        r2 += mul(yn, yn, out=tmp)
        radial = mul(r2, k["k3"])  # 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        radial += k["k2"]
        radial *= r2
        radial += k["k1"]
        radial *= r2
        radial += 1
        xd = mul(xn, radial)  # xn * radial + two_p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
        mul(k["two_p1"], xn, out=tmp)
        tmp *= yn
        xd += tmp
        mul(xn, 2, out=tmp)
        tmp *= xn
        tmp += r2
        tmp *= k["p2"]
        xd += tmp
        yd = mul(yn, radial, out=radial)  # yn * radial + p1 * (r2 + 2 * yn * yn) + two_p2 * xn * yn
        mul(yn, 2, out=tmp)
        tmp *= yn
        tmp += r2
        tmp *= k["p1"]
        yd += tmp
        mul(k["two_p2"], xn, out=tmp)
        tmp *= yn
        yd += tmp
        u = mul(k["fx"], xd, out=xd)  # fx * xd + skew * yd + cx
        u += mul(k["skew"], yd, out=tmp)
        u += k["cx"]
        v = mul(k["fy"], yd, out=yd)  # fy * yd + cy
        v += k["cy"]
        # sample_uv: NaN (behind the camera, or NaN points) reads column / row 0, as its
        # nan_to_num(nan=-1) and clamp(0, .) do; fmax/fmin map NaN to 0 and clamp infinities alike
        h, w = self.h, self.w
        u -= k["ox"]
        v -= k["oy"]
        if not k["unit_scale"]:  # (u - ox) * 1.0 is u - ox
            u *= k["scale"]
            v *= k["scale"]
        u += 1.0
        v += 1.0
        x = np.fmin(np.fmax(u, 0.0, out=u), w - 1, out=u)
        y = np.fmin(np.fmax(v, 0.0, out=v), h - 1, out=v)
        if np.fmin.reduce(xc2, axis=None, initial=np.inf) <= 1e-6:  # behind a camera (NaN is not)
            x[xc2 <= 1e-6] = 0.0
        xi = x.astype(np.int64)  # floor: x >= 0
        yi = y.astype(np.int64)
        np.minimum(xi, w - 2, out=xi)
        np.minimum(yi, h - 2, out=yi)
        fx = np.subtract(x, xi, out=x)
        fy = np.subtract(y, yi, out=y)
        yi *= w  # idx = base + yi * w + xi
        yi += k["base"]
        yi += xi
        idx = yi
        gx = np.subtract(1, fx, out=xc2)
        # top = flat[idx] * gx + flat1[idx] * fx; bottom likewise one row down; then
        # top * (1 - fy) + bottom * fy (the canvas' float32 corners promote exactly)
        corner = self.flat.take(idx)
        top = mul(corner, gx, out=tmp)
        top += mul(self.flat1.take(idx, out=corner), fx, out=r2)
        bottom = mul(self.flatw.take(idx, out=corner), gx, out=gx)
        bottom += mul(self.flatw1.take(idx, out=corner), fx, out=fx)
        top *= np.subtract(1, fy, out=r2)
        bottom *= fy
        top += bottom
        return top if self.cap is None else np.minimum(top, self.cap, out=top)


class RefinementMRF:
    """The MRF2 energy as a :class:`~spinemocap.track.pbp.PairwiseModel` (states (x, y, z))."""

    # the pairwise cost of (xs, xt) is that of (xt, xs), bit for bit: the midpoint's sum commutes,
    # and p = xs - xt only changes sign (exactly) before every use is squared
    symmetric_pairwise = True

    def __init__(
        self,
        tape: TapeGraph,
        rig: Rig,
        evidence: Sequence[EvidenceImage | None],
        config: MRF2Config,
        normals: np.ndarray | None = None,
        feasible_points: np.ndarray | None = None,
    ):
        if len(evidence) != len(rig):
            raise ValueError(f"{len(evidence)} evidence images for {len(rig)} cameras")
        self.tape = tape
        self.config = config
        self.cams = _TorchRig(rig)
        self.rig = rig
        self.evidence = list(evidence)
        self.stack = EvidenceStack(self.evidence)
        self.edges = tape.solid_edges
        solid = tape.solid
        self.rest = torch.tensor(tape.rest_length_mm[solid], dtype=torch.float64)
        duv = tape.uv_mm[self.edges[:, 0]] - tape.uv_mm[self.edges[:, 1]]  # expected p in tape frame
        self.duv = duv / np.linalg.norm(duv, axis=1, keepdims=True)
        self.fixed_normals = None if normals is None else np.asarray(normals, dtype=float)
        self.points = None if feasible_points is None or len(feasible_points) == 0 else np.asarray(feasible_points, float)
        n_cam = len(rig)
        self.visible = torch.zeros((tape.n_dots, n_cam), dtype=torch.float64)
        self.unary_weight = torch.zeros((tape.n_dots, n_cam), dtype=torch.float64)
        self.unseen = torch.zeros(tape.n_dots, dtype=torch.bool)
        self.start = torch.zeros((tape.n_dots, 3), dtype=torch.float64)  # set by refine_mrf2
        self.edge_visible = torch.zeros((len(self.edges), n_cam), dtype=torch.float64)
        self.edge_normal = torch.zeros((len(self.edges), 3), dtype=torch.float64)
        self.edge_alpha = torch.zeros((len(self.edges), 3), dtype=torch.float64)
        self._costs = _ImageCosts(self.cams, self.stack, config.cost_cap)
        self._vis_constants: dict[tuple, dict] = {}
        self._prepared: tuple[tuple, dict] | None = None
        self._prepared_from: tuple[np.ndarray, tuple] | None = None

    # ------------------------------------------------------------------ state-dependent parts
    def prepared_parameters(self) -> tuple:
        """The state-dependent parameters :meth:`prepare` sets, as objects: particle BP compares
        them by identity to know that costs it evaluated still hold (none was set again)."""
        return (self.visible, self.edge_visible, self.unary_weight, self.unseen, self.edge_normal, self.edge_alpha)

    def prepare(self, state: np.ndarray) -> None:
        """Set the state-dependent parameters (visibility, weights, edge directions) from
        ``state`` (D, 3); nothing to do when they were set from the same state (particle BP
        prepares again after an iteration that kept the state) and not replaced since."""
        state = np.asarray(state, dtype=np.float64)
        last = self._prepared_from
        if last is not None and all(a is b for a, b in zip(last[1], self.prepared_parameters())) \
                and np.array_equal(last[0], state):
            return
        self._prepare(state)
        self._prepared_from = (state.copy(), self.prepared_parameters())

    def _prepare(self, state: np.ndarray) -> None:
        normal, across, along = tape_frames(state, self.tape)
        if self.fixed_normals is not None:
            normal = self.fixed_normals
        visible = self.visibility(state, normal)
        if self.config.cost_cap is not None:
            # a view whose cost is already at the cap (an occluder, or off the tape) carries no
            # information about this dot: it does not count as seeing it
            at_cap = self._costs(state[:, 0], state[:, 1], state[:, 2]).T >= self.config.cost_cap - 1e-9
            visible &= ~at_cap
        self.visible = torch.from_numpy(visible.astype(np.float64))
        e0, e1 = self.edges[:, 0], self.edges[:, 1]
        self.edge_visible = self.visible[e0] * self.visible[e1]
        # theta5's I(x_s) + I(x_t) depend on one node each: they are summed into the unary
        # weights (same energy, and the pairwise tables then only sample the midpoints)
        contrast = torch.zeros_like(self.visible)
        contrast.index_add_(0, torch.from_numpy(e0), self.edge_visible)
        contrast.index_add_(0, torch.from_numpy(e1), self.edge_visible)
        self.unary_weight = self.visible + self.config.theta5 * contrast
        self.unseen = torch.from_numpy(~(self.visible.numpy() > 0).any(axis=1))
        n_e = normal[e0] + normal[e1]
        n_e /= np.maximum(np.linalg.norm(n_e, axis=1, keepdims=True), 1e-12)
        expected = self.duv[:, :1] * (across[e0] + across[e1]) + self.duv[:, 1:] * (along[e0] + along[e1])
        alpha = np.cross(n_e, expected)
        alpha /= np.maximum(np.linalg.norm(alpha, axis=1, keepdims=True), 1e-12)
        self.edge_normal = torch.from_numpy(n_e)
        self.edge_alpha = torch.from_numpy(alpha)

    def visibility(self, positions: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(D, C) bool: the dot projects inside camera c's image, camera c has evidence, and the
        dot's outward normal faces the camera (cosine above ``facing_cos``). All cameras at once:
        :meth:`visibility_per_camera`'s operations, each camera's products the same matrix
        products (a stack of the per-camera ones), the rest element by element."""
        out = np.zeros((len(positions), len(self.rig)), dtype=bool)
        cams = [c for c, ev in enumerate(self.evidence) if ev is not None]
        if not cams:
            return out
        k = self._visibility_constants(cams)
        cos, uv = self._facing_and_pixels(positions, normals, k)
        margin = self.config.image_margin_px
        u, v = uv[:, :, 0], uv[:, :, 1]
        with np.errstate(invalid="ignore"):
            inside = (u >= -0.5 + margin) & (u <= k["w"] - 0.5 - margin) & (v >= -0.5 + margin) & (v <= k["h"] - 0.5 - margin)
        out[:, cams] = ((cos > self.config.facing_cos) & inside).T
        return out

    @staticmethod
    def _facing_and_pixels(positions: np.ndarray, normals: np.ndarray, k: dict) -> tuple[np.ndarray, np.ndarray]:
        """(C', D) cosines between the dots' normals and their directions to the cameras, and
        (C', D, 2) ``Camera.project`` pixels, for the cameras of the constants ``k``."""
        pos = np.asarray(positions, float).reshape(-1, 3)
        to_cam = k["center"][:, None, :] - pos[None, :, :]  # (C', D, 3)
        cos = (to_cam * normals).sum(axis=2) / np.maximum(np.linalg.norm(to_cam, axis=2), 1e-9)
        pc = np.matmul(pos, k["RT"]) + k["t"][:, None, :]  # Camera.to_camera per camera
        with np.errstate(divide="ignore", invalid="ignore"):
            normalized = pc[:, :, :2] / pc[:, :, 2:3]
        normalized[pc[:, :, 2] <= 1e-9] = np.nan
        n_cam, n = pc.shape[:2]
        distorted = distort(normalized.reshape(-1, 2), k["dist"].repeat(n, axis=0)).reshape(n_cam, n, 2)
        return cos, np.matmul(distorted, k["KT"]) + k["c"][:, None, :]

    def _visibility_constants(self, cams: list[int]) -> dict:
        key = tuple(cams)
        got = self._vis_constants.get(key)
        if got is None:
            rig = [self.rig[c] for c in cams]
            got = {
                "center": np.stack([cam.center for cam in rig]),
                "RT": np.stack([cam.R for cam in rig]).transpose(0, 2, 1),  # each R.T, laid out as R.T is
                "t": np.stack([cam.t for cam in rig]),
                "dist": np.stack([np.asarray(cam.dist, float) for cam in rig]),
                "KT": np.stack([cam.K[:2, :2] for cam in rig]).transpose(0, 2, 1),
                "c": np.stack([cam.K[:2, 2] for cam in rig]),
                "w": np.array([[float(cam.size[0])] for cam in rig]),
                "h": np.array([[float(cam.size[1])] for cam in rig]),
            }
            self._vis_constants[key] = got
        return got

    def visibility_per_camera(self, positions: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """:meth:`visibility` camera by camera (the reference it is tested against)."""
        out = np.zeros((len(positions), len(self.rig)), dtype=bool)
        for c, (cam, ev) in enumerate(zip(self.rig, self.evidence)):
            if ev is None:
                continue
            to_cam = cam.center[None, :] - positions
            cos = (to_cam * normals).sum(axis=1) / np.maximum(np.linalg.norm(to_cam, axis=1), 1e-9)
            uv = cam.project(positions)
            out[:, c] = (cos > self.config.facing_cos) & cam.in_image(uv, margin=self.config.image_margin_px)
        return out

    # ------------------------------------------------------------------ energy terms (torch)
    def image_costs(self, x: torch.Tensor, cams: torch.Tensor | None = None) -> torch.Tensor:
        """(C, ...) evidence cost of points x (..., 3) in every camera (0 where none); with
        ``cams`` (C,) bool in those cameras only (C', ...)."""
        u, v = self.cams.project_uv(x, cams)  # (C, N) each
        cost = self.stack.sample_uv(u, v, cams).reshape((u.shape[0],) + x.shape[:-1])
        return cost if self.config.cost_cap is None else cost.clamp(max=self.config.cost_cap)

    @staticmethod
    def _weighted_sum(costs: Callable[[torch.Tensor | None], torch.Tensor], weight: torch.Tensor) -> torch.Tensor:
        """``(costs(None) * weight).sum(dim=0)`` over cameras (weight (C, ...) broadcasting
        against the costs), evaluating the costs only in the cameras with a nonzero weight: the
        others add exact zeros (the costs are finite), so the same sums."""
        cams = (weight != 0).reshape(weight.shape[0], -1).any(dim=1)
        if bool(cams.all()) or not bool(cams.any()):
            return (costs(None) * weight).sum(dim=0)
        return (costs(cams) * weight[cams]).sum(dim=0)

    def unary_t(self, x: torch.Tensor) -> torch.Tensor:
        """x (D, Q, 3) -> (D, Q): Eq. 10 plus theta5's per-node part of Eq. 11 (plus the anchor of
        unseen dots)."""
        image = self._weighted_sum(lambda cams: self.image_costs(x, cams), self.unary_weight.T[:, :, None])  # (D, Q)
        if not self.config.anchor_unseen or not bool(self.unseen.any()):
            return image
        pull = ((x - self.start[:, None, :]) ** 2).sum(dim=2)
        return image + self.config.anchor_unseen * self.unseen[:, None] * pull

    def pairwise_t(self, xs: torch.Tensor, xt: torch.Tensor, edge_index: torch.Tensor) -> torch.Tensor:
        """xs (M, Qs, 3), xt (M, Qt, 3) -> (M, Qs, Qt). The theta5 terms at the nodes themselves
        live in :meth:`unary_t`; here only the midpoint's ``-2 theta5 I_c(x_st)``."""
        c = self.config
        vis = self.edge_visible[edge_index].T  # (C, M)
        mid = 0.5 * (xs[:, :, None, :] + xt[:, None, :, :])
        contrast = -2.0 * self._weighted_sum(lambda cams: self.image_costs(mid, cams), vis[:, :, None, None])
        # p = xs - xt (M, Qs, Qt, 3) by components: the same sums as (p * p).sum(dim=3) and
        # (p * n).sum(dim=3), without the strided reductions
        dx, dy, dz = (xs[:, :, None, i] - xt[:, None, :, i] for i in range(3))
        length = torch.sqrt((dx * dx + dy * dy + dz * dz) + 1e-12)
        normal, alpha = self.edge_normal[edge_index], self.edge_alpha[edge_index]
        along_normal = dx * normal[:, 0, None, None] + dy * normal[:, 1, None, None] + dz * normal[:, 2, None, None]
        off_axis = dx * alpha[:, 0, None, None] + dy * alpha[:, 1, None, None] + dz * alpha[:, 2, None, None]
        rest = self.rest[edge_index][:, None, None]
        return (
            c.theta5 * contrast
            + c.theta6 * along_normal**2
            + c.theta7 * off_axis**2
            + c.theta8 * (length - rest) ** 2
        )

    def energy_t(self, x: torch.Tensor) -> torch.Tensor:
        """Eq. 6 at positions x (D, 3) as a differentiable scalar."""
        e0, e1 = torch.from_numpy(self.edges[:, 0]), torch.from_numpy(self.edges[:, 1])
        pair = self.pairwise_t(x[e0][:, None], x[e1][:, None], torch.arange(len(self.edges)))
        return self.unary_t(x[:, None]).sum() + pair.sum()

    # ------------------------------------------------------------------ PairwiseModel (numpy)
    # The same energy as unary_t / pairwise_t, computed in numpy by the same IEEE operations in the
    # same order (bit for bit; tests/track/test_track_fast_paths.py pins them): particle BP evaluates it
    # ~30 times per iteration on a few thousand points, where torch's per-operation cost, the
    # strided reads of (..., 3) tensors and the per-call camera indexing dominated.
    def _numpy_parameters(self) -> dict:
        """numpy views of the parameters ``prepare`` set (and the cameras with a nonzero weight),
        made again whenever one of those tensors was replaced."""
        key = (self.unary_weight, self.edge_visible, self.edge_normal, self.edge_alpha, self.unseen, self.start, self.rest)
        if self._prepared is not None and all(a is b for a, b in zip(self._prepared[0], key)):
            return self._prepared[1]
        n_cam = len(self.rig)

        def used(weight):  # (C, K) -> the cameras whose weight is nonzero somewhere, and their rows
            cams = np.flatnonzero((weight != 0).any(axis=1))
            if len(cams) == n_cam:
                return None, weight
            return cams, weight[cams]

        ucams, uw = used(self.unary_weight.numpy().T)
        ecams, ev = used(self.edge_visible.numpy().T)
        coef = None
        if self.config.anchor_unseen and bool(self.unseen.any()):
            # the torch expression's own factor (its dtype included: a float times a bool tensor)
            coef = (self.config.anchor_unseen * self.unseen[:, None]).numpy()
        params = {"ucams": ucams, "uw": uw, "ecams": ecams, "ev": ev, "coef": coef, "start": self.start.numpy(),
                  "normal": self.edge_normal.numpy(), "alpha": self.edge_alpha.numpy(), "rest": self.rest.numpy()}
        self._prepared = (key, params)
        return params

    def _weighted_costs(self, px, py, pz, cams, weight: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
        """``sum_c cost_c(points) * weight_c``: the points' coordinates (N,) each, ``weight``
        (C', M) for the cameras ``cams`` (None: all; an empty selection: no camera), each of the M
        weights shared by N / M consecutive points -> ``shape`` (N values). Cameras are added one
        after another from zero, as torch's ``sum(dim=0)`` does."""
        if cams is not None and len(cams) == 0:
            return np.zeros(shape)
        costs = self._costs(px, py, pz, cams)
        m = weight.shape[1]
        per = len(px) // m if m else 0
        return np.add.reduce(costs.reshape(len(costs), m, per) * weight[:, :, None], axis=0).reshape(shape)

    def unary(self, x: np.ndarray) -> np.ndarray:
        """:meth:`unary_t` in numpy (the same values)."""
        x = np.asarray(x, dtype=np.float64)
        p = self._numpy_parameters()
        flat = x.reshape(-1, 3)
        image = self._weighted_costs(flat[:, 0], flat[:, 1], flat[:, 2], p["ucams"], p["uw"], x.shape[:2])
        if p["coef"] is None:
            return image
        d = x - p["start"][:, None, :]
        return image + p["coef"] * (d**2).sum(axis=2)

    def unary_rows(self, nodes: np.ndarray, x: np.ndarray) -> np.ndarray:
        """:meth:`unary` of single points: node ``nodes[k]`` at ``x[k]`` (K, 3) -> (K,) (the
        same values as the matching entries of :meth:`unary`)."""
        x = np.asarray(x, dtype=np.float64)
        p = self._numpy_parameters()
        image = self._weighted_costs(x[:, 0], x[:, 1], x[:, 2], p["ucams"], p["uw"][:, nodes], (len(x),))
        if p["coef"] is None:
            return image
        d = x - p["start"][nodes]
        return image + p["coef"][nodes, 0] * (d**2).sum(axis=1)

    def pairwise(self, xs: np.ndarray, xt: np.ndarray, edge_index: np.ndarray) -> np.ndarray:
        """:meth:`pairwise_t` in numpy (the same values)."""
        c = self.config
        xs = np.asarray(xs, dtype=np.float64)
        xt = np.asarray(xt, dtype=np.float64)
        edge_index = np.asarray(edge_index)
        p = self._numpy_parameters()
        m, qs, qt = len(xs), xs.shape[1], xt.shape[1]
        sx, sy, sz = (xs[:, :, None, i] for i in range(3))
        tx, ty, tz = (xt[:, None, :, i] for i in range(3))
        mx, my, mz = (0.5 * (a + b) for a, b in ((sx, tx), (sy, ty), (sz, tz)))
        weighted = self._weighted_costs(mx.ravel(), my.ravel(), mz.ravel(), p["ecams"], p["ev"][:, edge_index], (m, qs, qt))
        contrast = -2.0 * weighted
        dx, dy, dz = sx - tx, sy - ty, sz - tz
        # torch's float64 sqrt, not numpy's: it is not always correctly rounded (1 ulp on ~1 % of
        # values with AVX-512), and the values are to stay those of pairwise_t
        length = torch.sqrt(torch.from_numpy((dx * dx + dy * dy + dz * dz) + 1e-12)).numpy()
        normal, alpha = p["normal"][edge_index], p["alpha"][edge_index]
        along_normal = dx * normal[:, 0, None, None] + dy * normal[:, 1, None, None] + dz * normal[:, 2, None, None]
        off_axis = dx * alpha[:, 0, None, None] + dy * alpha[:, 1, None, None] + dz * alpha[:, 2, None, None]
        rest = p["rest"][edge_index][:, None, None]
        return (
            c.theta5 * contrast
            + c.theta6 * along_normal**2
            + c.theta7 * off_axis**2
            + c.theta8 * (length - rest) ** 2
        )

    def extra_proposals(self, state: np.ndarray) -> np.ndarray | None:
        """P_knn: the nearest feasible points (when given) within a dot radius of the estimate."""
        k = self.config.knn
        if self.points is None or k <= 0:
            return None
        dist = np.linalg.norm(state[:, None, :] - self.points[None, :, :], axis=2)
        idx = np.argsort(dist, axis=1)[:, :k]
        near = np.take_along_axis(dist, idx, axis=1) < self.tape.spec.dot_diameter_mm
        return np.where(near[:, :, None], self.points[idx], state[:, None, :])

    # ------------------------------------------------------------------ continuous polish
    def polish(self, positions: np.ndarray, steps: int, max_step_mm: float) -> tuple[np.ndarray, list[float]]:
        """L-BFGS on the MRF2 energy from ``positions`` (D, 3); each dot stays within
        ``max_step_mm`` of its start (a trust region: the evidence is only locally informative).
        Returns the best positions and the energy after each step."""
        self.prepare(positions)
        start = torch.from_numpy(positions.copy())
        delta = torch.zeros_like(start, requires_grad=True)
        opt = torch.optim.LBFGS([delta], lr=1.0, max_iter=10, line_search_fn="strong_wolfe")

        def bounded(d):
            return max_step_mm * torch.tanh(d / max_step_mm)

        def closure():
            opt.zero_grad()
            energy = self.energy_t(start + bounded(delta))
            energy.backward()
            return energy

        best = positions.copy()
        with torch.no_grad():
            best_energy = float(self.energy_t(start))
        history = []
        for _ in range(steps):
            opt.step(closure)
            with torch.no_grad():
                x = start + bounded(delta)
                energy = float(self.energy_t(x))
            if energy < best_energy:
                best, best_energy = x.numpy().copy(), energy
            history.append(best_energy)
        return best, history


class TemplateEvidenceScore:
    """Mean image cost of candidate tape templates, for MRF1's offset choice (beyond the paper).

    A template shifted along the tape by two rows fits a partial feasible set as well as the
    right one, but puts its end rows off the tape in the images (high outside-mask cost) or
    its dots on dark tape. Call with templates (C, D, 3) mm -> (C,) mean cost over the dots'
    facing, in-image cameras (Eq. 10 per dot-view)."""

    def __init__(self, rig: Rig, evidence: Sequence[EvidenceImage | None], tape: TapeGraph,
                 facing_cos: float = 0.05, margin_px: float = 2.0, cost_cap: float | None = 1.0):
        self.rig, self.tape = rig, tape
        self.cams = _TorchRig(rig)
        self.stack = EvidenceStack(list(evidence))
        self.has_image = np.array([e is not None for e in evidence])
        self.facing_cos, self.margin_px, self.cost_cap = facing_cos, margin_px, cost_cap

    def __call__(self, templates: np.ndarray) -> np.ndarray:
        templates = np.asarray(templates, dtype=float)
        out = np.zeros(len(templates))
        with _torch_single_thread(), torch.no_grad():
            for i, pos in enumerate(templates):
                normal = tape_frames(pos, self.tape)[0]
                use = np.zeros((len(self.rig), len(pos)), dtype=bool)
                for c, cam in enumerate(self.rig):
                    to_cam = cam.center - pos
                    cos = (to_cam * normal).sum(axis=1) / np.maximum(np.linalg.norm(to_cam, axis=1), 1e-9)
                    use[c] = self.has_image[c] & (cos > self.facing_cos) & cam.in_image(cam.project(pos), self.margin_px)
                cost = self.stack.sample_torch(self.cams.project(torch.from_numpy(pos))).numpy()
                if self.cost_cap is not None:
                    cost = np.minimum(cost, self.cost_cap)
                out[i] = cost[use].mean() if use.any() else 0.0
        return out


@contextmanager
def _torch_single_thread() -> Iterator[None]:
    """MRF2's tensors are small (thousands of elements): torch's intra-op thread pool costs far
    more than it gains there, most of all on a busy machine, so run single-threaded.
    Set only when it differs: a ``torch.set_num_threads`` call, even to the same count, slows the
    network passes after it (see ``detect.detector``), and the detector already runs one thread."""
    before = torch.get_num_threads()
    if before != 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if before != 1:
            torch.set_num_threads(before)


def refine_mrf2(
    positions: np.ndarray,
    tape: TapeGraph,
    rig: Rig,
    evidence: Sequence[EvidenceImage | None],
    config: MRF2Config | None = None,
    normals: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
    feasible_points: np.ndarray | None = None,
) -> MRFResult:
    """Refine labelled dot positions (D, 3) mm on the camera images.

    ``evidence``: one :class:`EvidenceImage` per rig camera (None where a camera has no image).
    ``normals`` (D, 3): outward dot normals for the facing test; default: from the dots' tape
    frames. ``feasible_points`` (K, 3): optional P_knn proposals. Returned positions are moved
    ``tape.spec.thickness_mm`` inward along the dots' normals (tape surface -> skin).
    ``energy_history``: the energy after each PBP iteration, then after each polish step.
    ``extra``: ``visible`` (D, C) bool (cameras used per dot), ``pbp_positions`` (D, 3, on the
    tape surface), ``polish_history``."""
    with _torch_single_thread():
        return _refine(positions, tape, rig, evidence, config or MRF2Config(), normals, rng, feasible_points)


def _refine(positions, tape, rig, evidence, config, normals, rng, feasible_points) -> MRFResult:
    init = np.asarray(positions, dtype=float).reshape(tape.n_dots, 3)
    model = RefinementMRF(tape, rig, evidence, config, normals=normals, feasible_points=feasible_points)
    model.start = torch.from_numpy(init.copy())
    result = ParticleBP(model, config.pbp(), rng).run(init)
    state, history = result.state, list(result.energy_history)
    pbp_state = state.copy()
    polish_history: list[float] = []
    if config.polish and config.polish_steps > 0:
        state, polish_history = model.polish(state, config.polish_steps, config.polish_max_step_mm)
        history += polish_history
    model.prepare(state)
    # the images show the holes' rims on the tape's top surface; report the skin underneath
    skin = state - tape.spec.thickness_mm * tape_frames(state, tape)[0]
    return MRFResult(
        positions=skin,
        energy_history=history,
        extra={
            "visible": model.visible.numpy() > 0,
            "pbp_positions": pbp_state,
            "energy_baselines": result.baselines,
            "polish_history": polish_history,
            "final_energy": mrf_energy(model, state),
        },
    )
