"""A small software renderer in numpy for scripts/rendered_benchmark.py: z-buffered triangle
rasterization with barycentric texture sampling, Lambertian shading, orthographic (weak
perspective) and pinhole perspective cameras, and the image degradations of the benchmark.

Image coordinates are continuous: origin at the top-left corner of the top-left pixel, x right,
y down, so pixel (i, j) covers [i, i+1) x [j, j+1) and its centre is (i + 0.5, j + 0.5); the same
as MediaPipe's normalized coordinates times the image size. Model coordinates: the project's model
frame (x towards the subject's left, y up, z towards the camera, mm).
"""

import cv2
import numpy as np


def rot_pose_para(pitch, yaw, roll):
    """R = Rx(pitch) Ry(yaw) Rz(roll), degrees, Pose_Para (docs: /work/shared/data/README.md)."""
    p, y, r = np.radians([pitch, yaw, roll])
    cx, sx, cy, sy, cz, sz = np.cos(p), np.sin(p), np.cos(y), np.sin(y), np.cos(r), np.sin(r)
    rx = np.array([[1, 0, 0], [0, cx, sx], [0, -sx, cx]])
    ry = np.array([[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]])
    rz = np.array([[cz, sz, 0], [-sz, cz, 0], [0, 0, 1]])
    return rx @ ry @ rz


def pose_para_angles(R):
    """(pitch, yaw, roll) in degrees of R = Rx(pitch) Ry(yaw) Rz(roll)."""
    yaw = -np.degrees(np.arcsin(np.clip(R[0, 2], -1, 1)))
    roll = np.degrees(np.arctan2(R[0, 1], R[0, 0]))
    pitch = np.degrees(np.arctan2(R[1, 2], R[2, 2]))
    return float(pitch), float(yaw), float(roll)


class Camera:
    """Projects model points rotated by R into the image.

    ortho: [u, -v] = s * (R X)[0:2] + [tx, -ty]   (s px/mm; (tx, ty) is the image point of the
           model origin).
    perspective: camera space Xc = R X + T (x right, y up, z towards the viewer; the camera at the
           origin looking down -z, as MediaPipe's face geometry), u = cx + fx * Xc / -Zc,
           v = cy - fy * Yc / -Zc.
    """

    def __init__(self, kind, width, height, s=None, t=None, fx=None, fy=None, cx=None, cy=None,
                 T=None):
        self.kind, self.width, self.height = kind, width, height
        self.s, self.t = s, None if t is None else np.asarray(t, float)
        self.fx, self.fy, self.cx, self.cy = fx, fy, cx, cy
        self.T = None if T is None else np.asarray(T, float)

    def project(self, Xr):
        """Xr: rotated model points (N, 3). Returns (uv (N, 2) px, depth (N,) larger = nearer,
        w (N,) the perspective divisor (1 for ortho))."""
        if self.kind == "ortho":
            uv = np.stack([self.s * Xr[:, 0] + self.t[0], -self.s * Xr[:, 1] + self.t[1]], 1)
            return uv, Xr[:, 2].copy(), np.ones(len(Xr))
        Xc = Xr + self.T
        w = -Xc[:, 2]
        uv = np.stack([self.cx + self.fx * Xc[:, 0] / w, self.cy - self.fy * Xc[:, 1] / w], 1)
        return uv, -w, w

    def describe(self):
        d = {"kind": self.kind, "width": self.width, "height": self.height}
        if self.kind == "ortho":
            d.update(scale_px_per_mm=round(float(self.s), 5),
                     origin_px=[round(float(v), 3) for v in self.t])
        else:
            d.update(fx=round(float(self.fx), 3), fy=round(float(self.fy), 3),
                     cx=round(float(self.cx), 3), cy=round(float(self.cy), 3),
                     translation_mm=[round(float(v), 3) for v in self.T])
        return d


def vertex_normals(V, tris):
    n = np.cross(V[tris[:, 1]] - V[tris[:, 0]], V[tris[:, 2]] - V[tris[:, 0]])
    vn = np.zeros_like(V)
    for k in range(3):
        np.add.at(vn, tris[:, k], n)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-9)


def rasterize(uv, depth, w, tris, width, height, cull=True):
    """Z-buffer. Returns (pix (P,), tri (P,), bary (P, 3) perspective-correct) for the covered
    pixels (pix = row * width + col), nearest triangle first."""
    P = uv[tris]  # (T, 3, 2)
    a, b, c = P[:, 0], P[:, 1], P[:, 2]
    e1, e2 = b - a, c - a
    d = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    # Triangles are wound anticlockwise seen from outside with y up: clockwise on screen (y down),
    # d < 0. Back faces (d > 0) are culled.
    keep = np.abs(d) > 1e-9
    if cull:
        keep &= d < 0
    xmin = np.ceil(P[:, :, 0].min(1) - 0.5).astype(np.int64)
    xmax = np.floor(P[:, :, 0].max(1) - 0.5).astype(np.int64)
    ymin = np.ceil(P[:, :, 1].min(1) - 0.5).astype(np.int64)
    ymax = np.floor(P[:, :, 1].max(1) - 0.5).astype(np.int64)
    xmin, ymin = np.maximum(xmin, 0), np.maximum(ymin, 0)
    xmax, ymax = np.minimum(xmax, width - 1), np.minimum(ymax, height - 1)
    bw, bh = xmax - xmin + 1, ymax - ymin + 1
    keep &= (bw > 0) & (bh > 0)
    ids = np.nonzero(keep)[0]
    bw, bh = bw[ids], bh[ids]
    counts = bw * bh
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    ti = np.repeat(np.arange(len(ids)), counts)
    starts = np.cumsum(counts) - counts
    local = np.arange(total) - starts[ti]
    px = xmin[ids][ti] + local % bw[ti]
    py = ymin[ids][ti] + local // bw[ti]
    tri = ids[ti]
    qx = px + 0.5 - a[tri, 0]
    qy = py + 0.5 - a[tri, 1]
    dd = d[tri]
    l1 = (qx * e2[tri, 1] - qy * e2[tri, 0]) / dd
    l2 = (e1[tri, 0] * qy - e1[tri, 1] * qx) / dd
    l0 = 1 - l1 - l2
    eps = -1e-7
    inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
    tri, px, py = tri[inside], px[inside], py[inside]
    L = np.stack([l0[inside], l1[inside], l2[inside]], 1)
    z = (L * depth[tris[tri]]).sum(1)
    pix = py * width + px
    order = np.lexsort((-z, pix))
    pix, tri, L = pix[order], tri[order], L[order]
    first = np.ones(len(pix), bool)
    first[1:] = pix[1:] != pix[:-1]
    pix, tri, L = pix[first], tri[first], L[first]
    # Perspective-correct weights: l_i / w_i, normalized.
    Lw = L / w[tris[tri]]
    Lw /= Lw.sum(1, keepdims=True)
    return pix, tri, Lw


def zbuffer_depth(pix, tri, L, depth, tris, width, height):
    zb = np.full(width * height, -np.inf)
    zb[pix] = (L * depth[tris[tri]]).sum(1)
    return zb.reshape(height, width)


def sample(texture, pix, t_uv, W, H):
    mapx = np.full(W * H, -10.0, np.float32)
    mapy = np.full(W * H, -10.0, np.float32)
    mapx[pix] = t_uv[:, 0] - 0.5
    mapy[pix] = t_uv[:, 1] - 0.5
    return cv2.remap(texture, mapx.reshape(H, W), mapy.reshape(H, W), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).astype(np.float32)


def render(Xr, tris, tex_uv, texture, cam, background, light=None, cull=True, sym=None):
    """Renders the textured mesh, its vertices already posed (Xr, model frame turned). `light`: None (texture as is) or a dict with
    `dir` (unit vector, camera frame, towards the light), `ambient`, `gain` (3,) colour gain.
    Returns (image uint8 HxWx3, mask float HxW, uv (N, 2) of every vertex, depth (N,),
    z-buffer HxW)."""
    W, H = cam.width, cam.height
    uv, depth, w = cam.project(Xr)
    pix, tri, L = rasterize(uv, depth, w, tris, W, H, cull=cull)
    t_uv = (L[:, :, None] * tex_uv[tris[tri]]).sum(1)
    col = sample(texture, pix, t_uv, W, H)
    if sym is not None:
        # soft symmetry: blend in the mirror side's texture where the photo was blind
        uv2, wv = sym
        a = (L * wv[tris[tri]]).sum(1)
        k = a > 1e-3
        if k.any():
            col2 = sample(texture, pix[k], (L[k, :, None] * uv2[tris[tri[k]]]).sum(1), W, H)
            al = np.zeros(W * H, np.float32)
            al[pix[k]] = a[k]
            al = al.reshape(H, W, 1)
            col = (1 - al) * col + al * col2
    if light is not None:
        n = vertex_normals(Xr, tris)
        pn = (L[:, :, None] * n[tris[tri]]).sum(1)
        pn /= np.maximum(np.linalg.norm(pn, axis=1, keepdims=True), 1e-9)
        lam = np.clip(pn @ np.asarray(light["dir"]), 0, 1)
        # The photo already holds its own (roughly frontal) lighting: the light changes it
        # relative to a frontal one.
        front = np.clip(pn[:, 2], 0, 1)
        amb = light["ambient"]
        shade = (amb + (1 - amb) * lam) / (amb + (1 - amb) * (0.5 + 0.5 * front))
        sh = np.ones(W * H, np.float32)
        sh[pix] = np.clip(shade, 0.25, 1.6)
        col *= sh.reshape(H, W, 1) * np.asarray(light["gain"], np.float32)
    mask = np.zeros(W * H, np.float32)
    mask[pix] = 1
    mask = mask.reshape(H, W)
    # Soft silhouette edge (cheap anti-aliasing).
    alpha = cv2.GaussianBlur(mask, (3, 3), 0.6)[:, :, None]
    img = alpha * col + (1 - alpha) * background.astype(np.float32)
    img = np.clip(img, 0, 255).astype(np.uint8)
    zb = zbuffer_depth(pix, tri, L, depth, tris, W, H)
    counts = np.bincount(tri, minlength=len(tris))
    return img, mask, uv, depth, zb, counts


def stretch_stats(uv, tex_uv, tris, counts, ref):
    """How much the texture is magnified on screen, triangle by triangle (screen area over
    texture area, divided by `ref`, the magnification of a surface facing both the photo's and
    the render's camera), over the drawn pixels of `tris`: the pixel-weighted 90th percentile and
    the share of pixels magnified more than 2.5x in area (the texture seen at a grazing angle in
    the photo and stretched by the render)."""

    def area(P):
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])

    a_s, a_t = area(uv[tris]), area(tex_uv[tris])
    k = counts > 0
    if not k.any():
        return {"face_px": 0, "p90": None, "share_over_2_5": None}
    st = a_s[k] / np.maximum(a_t[k], 1e-6) / ref
    w = counts[k].astype(float)
    o = np.argsort(st)
    cw = np.cumsum(w[o]) / w.sum()
    p90 = float(st[o][np.searchsorted(cw, 0.9)])
    return {"face_px": int(w.sum()), "p90": round(p90, 2),
            "share_over_2_5": round(float(w[st > 2.5].sum() / w.sum()), 3)}


def visible(points_uv, points_depth, zb, tol):
    """Visibility of points by the z-buffer: inside the image, and somewhere in the 3x3 pixels
    around the point the surface drawn is not in front of it by more than `tol` (depth units, mm)
    or nothing is drawn. (The nearest drawn depth of the window would call points on steep
    slopes, like the sides of the nose, hidden.)"""
    H, W = zb.shape
    out = np.zeros(len(points_uv), bool)
    for k, ((u, v), z) in enumerate(zip(points_uv, points_depth)):
        i, j = int(np.floor(u)), int(np.floor(v))
        if not (0 <= i < W and 0 <= j < H):
            continue
        win = zb[max(j - 1, 0): j + 2, max(i - 1, 0): i + 2]
        out[k] = bool((win <= z + tol).any())  # -inf (nothing drawn) counts as not in front
    return out


def background(rng, width, height):
    """A smooth random background: a two-colour gradient with soft low-frequency blobs and a
    little noise."""
    c0 = rng.uniform(20, 235, 3)
    c1 = rng.uniform(20, 235, 3)
    ang = rng.uniform(0, 2 * np.pi)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    g = (np.cos(ang) * xx / width + np.sin(ang) * yy / height)
    g = (g - g.min()) / max(g.max() - g.min(), 1e-6)
    img = c0[None, None] * (1 - g[..., None]) + c1[None, None] * g[..., None]
    small = rng.normal(0, 18, (6, 6, 3)).astype(np.float32)
    img += cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    img += rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def degrade(img, rng_params):
    """Applies blur (Gaussian sigma px), noise (sigma, 0-255) and JPEG (quality) as given."""
    out = img
    if rng_params.get("blur_sigma", 0) > 0:
        out = cv2.GaussianBlur(out, (0, 0), rng_params["blur_sigma"])
    if rng_params.get("noise_sigma", 0) > 0:
        noise = np.random.default_rng(rng_params["noise_seed"]).normal(
            0, rng_params["noise_sigma"], out.shape)
        out = np.clip(out.astype(np.float32) + noise, 0, 255).astype(np.uint8)
    q = rng_params.get("jpeg_quality")
    if q:
        ok, buf = cv2.imencode(".jpg", out[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(q)])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1].copy()
    return out
