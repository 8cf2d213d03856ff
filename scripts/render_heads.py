"""Identities and textured 3D heads for scripts/rendered_benchmark.py.

Per identity (one face of a real photo shipped inside a package):
- a texture: a square crop of the photo around the face, resampled to TEX x TEX px;
- the photo's points on it: MediaPipe FaceMesh (478, with its z) and dlib (68, 5);
- two geometries, each a head mesh in the model frame (x towards the subject's left, y up, z
  towards the camera, mm) whose first 468 vertices are MediaPipe's mesh (their texture
  coordinates are MediaPipe's points on the crop), followed by a shell beyond the face oval
  (forehead, skull, sides, back of the head), two ears and a neck with shoulders, textured from
  the crop's pixels around the face:
  (a) "mediapipe": MediaPipe's own 3D landmarks on the photo (pixels, z in the scale of x), turned
      into the model frame and scaled to mm by a similarity Procrustes fit of its ibug68 points to
      geometry (b)'s frontal 68 points: a real person's shape as MediaPipe sees it. Truth is
      relative: its frontal direction is only as good as that alignment (a constant per-identity
      offset of a few degrees).
  (b) "bfm": the bfm68 morphable model (mean + 40 identity + 10 expression bases, Gaussian prior
      around the published coefficient means) fitted under weak perspective to MediaPipe's points
      on the photo mapped to ibug68 (2D only; MediaPipe's depth is not used); the canonical MediaPipe mesh is similarity-aligned to the fitted frontal 68
      points and then deformed through the 68-point correspondence by a 3D thin-plate spline, so
      the dense surface is in the bfm model frame and the truth is absolute.
"""

import json
import os
import zipfile

import cv2
import numpy as np

import render_raster as rr

TEX = 640  # texture crop, px: 4 dlib boxes wide, the face about 160 px


# ---------------------------------------------------------------- photos
def load_photos(wheel_path):
    """(name, RGB image) of the photographs: scikit-image's astronaut, and insightface's t1.jpg
    and Tom_Hanks_54745.png read out of the wheel archive (not installed)."""
    from skimage import data

    out = [("skimage/astronaut", data.astronaut())]
    with zipfile.ZipFile(wheel_path) as z:
        for member in ("insightface/data/images/t1.jpg",
                       "insightface/data/images/Tom_Hanks_54745.png"):
            buf = np.frombuffer(z.read(member), np.uint8)
            img = cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1].copy()
            out.append(("insightface/" + os.path.basename(member), img))
    return out


def face_boxes(dl, name, img, multi):
    """[(identity name, image, (cx, cy, w))] for every face dlib finds in a photo, left to right.
    Small photos (Tom Hanks is a 112x112 aligned crop) are upscaled 3x first. A photo of one
    person (multi False) keeps only dlib's best-scoring face (on the astronaut dlib also reports
    a weak false face)."""
    if max(img.shape[:2]) < 300:
        img = cv2.resize(img, None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)
    rects, scores, _ = dl.detector.run(img, 1, 0.0)
    if not multi:
        rects = [rects[int(np.argmax(scores))]] if len(rects) else []
    faces = sorted(rects, key=lambda r: r.center().x)
    stem = os.path.splitext(name)[0]
    out = []
    for k, r in enumerate(faces):
        ident = stem if len(faces) == 1 else f"{stem}#{k}"
        out.append((ident, img, (r.center().x + 0.5, r.center().y + 0.5, r.width())))
    return out


def crop_texture(img, box, size=TEX, factor=4.0):
    """A square crop around a dlib box (side = factor x box width, centred a little above the box
    centre, borders replicated), resampled to size x size."""
    cx, cy, w = box
    side = factor * w
    x0, y0 = cx - side / 2, cy - 0.08 * side - side / 2
    k = size / side
    A = np.array([[k, 0, -k * x0], [0, k, -k * y0]], np.float64)
    return cv2.warpAffine(img, A, (size, size), flags=cv2.INTER_CUBIC,
                          borderMode=cv2.BORDER_REPLICATE)


# ---------------------------------------------------------------- shapes
def load_canonical(data_dir):
    with open(os.path.join(data_dir, "mediapipe/canonical_face_468.json")) as f:
        c = json.load(f)
    return (np.array(c["vertices"], float), np.array(c["triangles"], np.int64),
            [list(ix) for ix in c["ibug68_from_mediapipe"]["indices"]])


def load_bfm(data_dir):
    with open(os.path.join(data_dir, "bfm68/morphable_model.json")) as f:
        m = json.load(f)
    mean = np.array(m["mean"], float)
    B = np.concatenate([np.array(m["shape_basis"], float), np.array(m["expression_basis"], float)])
    mu = np.concatenate([np.array(m["shape_coef_mean"], float),
                         np.array(m["expression_coef_mean"], float)])
    return mean, B, mu


def ibug_points(V, ibug_ix):
    return np.array([V[ix].mean(0) for ix in ibug_ix])


def weak_perspective(X, q):
    """Least-squares weak perspective q ~ s (R X)[0:2] + t (q with y up). Returns s, R, t."""
    Xc, qc = X - X.mean(0), q - q.mean(0)
    P = np.linalg.lstsq(Xc, qc, rcond=None)[0].T  # 2x3
    U, S, Vt = np.linalg.svd(P, full_matrices=False)
    R2 = U @ Vt
    R = np.vstack([R2, np.cross(R2[0], R2[1])])
    s = S.mean()
    t = q.mean(0) - s * (X.mean(0) @ R[:2].T)
    return s, R, t


def fit_bfm(lm_px, mean, B, mu, iters=30):
    """Fits bfm68 to 68 image points (y down) under weak perspective with a Gaussian prior
    (coefficients in standard deviations, prior N(mu, 1)). Returns (shape 68x3 model frame,
    coefficients, s, R, t, rms px)."""
    q = np.stack([lm_px[:, 0], -lm_px[:, 1]], 1)
    iod = np.linalg.norm(lm_px[36:42].mean(0) - lm_px[42:48].mean(0))
    sigma = 0.04 * iod  # landmark noise, px
    coef = mu.copy()
    Bf = B.reshape(len(B), -1).T  # (204, 50)
    for _ in range(iters):
        X = mean + (Bf @ coef).reshape(68, 3)
        s, R, t = weak_perspective(X, q)
        # q - t = s R2 (mean + B c)
        A = s * np.einsum("ij,pjk->pik", R[:2], B.transpose(1, 2, 0)).reshape(-1, len(coef))
        # A rows: point p, coord i; B.transpose(1,2,0): (68, 3, 50)
        b = (q - t - s * mean @ R[:2].T).reshape(-1)
        lhs = A.T @ A / sigma**2 + np.eye(len(coef))
        rhs = A.T @ b / sigma**2 + mu
        coef = np.linalg.solve(lhs, rhs)
    X = mean + (Bf @ coef).reshape(68, 3)
    s, R, t = weak_perspective(X, q)
    res = s * X @ R[:2].T + t - q
    return X, coef, s, R, t, float(np.sqrt((res**2).sum(1).mean()))


def similarity(A, B):
    """s, R, t minimizing |s R A + t - B| (rows are points)."""
    ma, mb = A.mean(0), B.mean(0)
    A0, B0 = A - ma, B - mb
    U, S, Vt = np.linalg.svd(B0.T @ A0)
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = (S * np.diag(D)).sum() / (A0**2).sum()
    return s, R, mb - s * ma @ R.T


def tps3(src, dst, reg=1.0):
    """A 3D thin-plate spline (kernel |r|) from control points src to dst; returns a function."""
    n = len(src)
    K = np.linalg.norm(src[:, None] - src[None], axis=2)
    P = np.hstack([np.ones((n, 1)), src])
    L = np.zeros((n + 4, n + 4))
    L[:n, :n] = K + reg * np.eye(n)
    L[:n, n:] = P
    L[n:, :n] = P.T
    rhs = np.zeros((n + 4, 3))
    rhs[:n] = dst
    sol = np.linalg.solve(L, rhs)
    w, a = sol[:n], sol[n:]

    def f(X):
        Kx = np.linalg.norm(X[:, None] - src[None], axis=2)
        return Kx @ w + np.hstack([np.ones((len(X), 1)), X]) @ a

    return f


# ---------------------------------------------------------------- head beyond the face
def boundary_loop(tris):
    """The ordered boundary vertices of the (single) open boundary of the face mesh."""
    from collections import Counter

    cnt = Counter()
    directed = {}
    for t in tris:
        for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0])):
            cnt[tuple(sorted((a, b)))] += 1
            directed[(a, b)] = True
    nxt = {}
    for (a, b) in directed:
        if cnt[tuple(sorted((a, b)))] == 1:
            nxt[a] = b
    start = next(iter(nxt))
    loop = [start]
    while nxt[loop[-1]] != start:
        loop.append(nxt[loop[-1]])
    return np.array(loop)


def orient_outward(V, tris, centre_of):
    """Flips triangles so that their normals point away from centre_of(triangle centroids)."""
    n = np.cross(V[tris[:, 1]] - V[tris[:, 0]], V[tris[:, 2]] - V[tris[:, 0]])
    cen = V[tris].mean(1)
    flip = (n * (cen - centre_of(cen))).sum(1) < 0
    tris = tris.copy()
    tris[flip] = tris[flip][:, ::-1]
    return tris


def build_head(face_V, face_tris, face_uv, photo_cam, rings=9):
    """Extends a 468-vertex face (model frame, mm, roughly frontal) to a head: a shell from the
    face oval over the skull to the back of the head (an ellipsoid sized from the face), and a
    neck widening to shoulders. The texture coordinates of the new vertices come from the photo
    camera (s, R, t: where the photo shows a model point), corrected at the oval so the texture
    is continuous there; along each column of the shell they never move back towards the face
    (beyond the photo's silhouette the shell repeats the pixels at the silhouette: hair, or
    what surrounds the head). Returns (V, tris, uv, info)."""
    s_ph, R_ph, t_ph = photo_cam

    def photo_uv(X):
        q = s_ph * X @ R_ph[:2].T + t_ph
        return np.stack([q[:, 0], -q[:, 1]], 1)

    loop = boundary_loop(face_tris)
    ov = face_V[loop]
    face_w = ov[:, 0].max() - ov[:, 0].min()
    top, chin = ov[:, 1].max(), ov[:, 1].min()
    # Head ellipsoid: half-width a little more than the oval, centre behind the oval's sides.
    a = 0.55 * face_w
    b = 0.62 * (top - chin) + 12
    cz = 1.3 * a
    lat = ov[np.argsort(np.abs(ov[:, 0]))[-4:]]
    c = np.array([0.0, chin + 0.58 * (top - chin) + 8, lat[:, 2].mean() - 8.0])
    radii = np.array([a, b, cz])
    u = (ov - c) / radii
    rho = np.linalg.norm(u, axis=1)
    d = u / rho[:, None]
    theta0 = np.arccos(np.clip(d[:, 2], -1, 1))
    phi = np.arctan2(d[:, 1], d[:, 0])
    theta_end = np.pi * 0.97
    cols = []
    for k in range(1, rings + 1):
        f = k / rings
        th = theta0 + (theta_end - theta0) * f
        r = rho + (1.0 - rho) * min(1.0, 2.5 * f)
        p = c + radii * r[:, None] * np.stack(
            [np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.cos(th)], 1)
        cols.append(p)
    shell = np.stack(cols)  # (rings, n, 3)
    n = len(loop)
    V = [face_V]
    base = len(face_V)
    ring_idx = [loop] + [base + k * n + np.arange(n) for k in range(rings)]
    V.append(shell.reshape(-1, 3))
    pole = base + rings * n
    V.append((c + radii * np.array([0, 0, -1.0]))[None])
    tris = [face_tris]
    for k in range(rings):
        r0, r1 = ring_idx[k], ring_idx[k + 1]
        for i in range(n):
            j = (i + 1) % n
            tris.append([[r0[i], r0[j], r1[j]], [r0[i], r1[j], r1[i]]])
    for i in range(n):
        tris.append([[ring_idx[-1][i], ring_idx[-1][(i + 1) % n], pole]])
    shell_tris = np.concatenate([np.array(t).reshape(-1, 3) for t in tris[1:]])
    shell_tris = orient_outward(np.concatenate(V), shell_tris, lambda x: c)

    # Texture of the shell: photo projection, continuous at the oval. Where the photo shows a
    # column of the shell (its projection moves away from the face) the shell takes those
    # pixels (forehead, hair, the sides of the head); beyond the photo's silhouette (sides and
    # back of the head, which the photo does not show) it takes the hair that the photo shows
    # above the forehead, from the column nearest the top at the same side.
    off = face_uv[loop] - photo_uv(ov)
    centre_uv = photo_uv(c[None])[0]
    shell_uv = np.zeros((rings, n, 2))
    hidden = np.zeros((rings, n), bool)
    prev_r = np.linalg.norm(face_uv[loop] - centre_uv, axis=1)
    for k in range(rings):
        q = photo_uv(shell[k]) + off * max(0.0, 1 - (k + 1) / 3)
        r = np.linalg.norm(q - centre_uv, axis=1)
        hidden[k] = (r < prev_r + 0.5) | (hidden[k - 1] if k else False)
        shell_uv[k] = q
        prev_r = np.maximum(r, prev_r)
    vis_last = np.where(hidden.any(0), hidden.argmax(0) - 1, rings - 1)
    # Where the photo's silhouette falls varies from column to column: a running minimum over
    # neighbouring columns keeps the seam between the photo's pixels and the hair from zigzagging.
    vis_last = np.min(np.stack([np.roll(vis_last, k) for k in (-2, -1, 0, 1, 2)]), 0)
    hidden = np.arange(rings)[:, None] > vis_last[None, :]
    for i in range(n):
        # the donor column: phi pulled towards the top of the head (phi = 90 degrees)
        target = np.pi / 2 + 0.35 * (((phi[i] - np.pi / 2) + np.pi) % (2 * np.pi) - np.pi)
        dist = np.abs(((phi - target) + np.pi) % (2 * np.pi) - np.pi)
        dist[vis_last < 1] = np.inf
        j = int(np.argmin(dist))
        # the outer half of what the photo shows above the forehead: hair more than skin
        donor = shell_uv[max(vis_last[j], 0) // 2: max(vis_last[j], 0) + 1, j]
        for k in range(rings):
            if hidden[k, i]:
                # walk back and forth over the donor's visible hair band
                m = len(donor)
                kk = (k - vis_last[i]) % (2 * m)
                shell_uv[k, i] = donor[min(kk if kk < m else 2 * m - 1 - kk, m - 1)]
    pole_uv = shell_uv[-1].mean(0)[None]

    # Neck and shoulders: an elliptic tube below the head, widening at the bottom.
    m = 28
    ang = np.linspace(0, 2 * np.pi, m, endpoint=False)
    levels = [(c[1] - 0.35 * b, 0.62, 0.62), (chin - 10, 0.62, 0.62), (chin - 45, 0.64, 0.64),
              (chin - 80, 0.75, 0.7), (chin - 105, 1.3, 0.85), (chin - 125, 2.0, 0.9),
              (chin - 190, 2.3, 0.95)]
    neck = []
    nz = c[2] + 0.25 * cz
    for y, kx, kz in levels:
        neck.append(np.stack([kx * a * np.cos(ang), np.full(m, y), nz + kz * a * np.sin(ang)], 1))
    neck = np.concatenate(neck)
    nbase = pole + 1
    ntris = []
    for L in range(len(levels) - 1):
        for i in range(m):
            j = (i + 1) % m
            p0, p1 = nbase + L * m + i, nbase + L * m + j
            q0, q1 = p0 + m, p1 + m
            ntris += [[p0, p1, q1], [p0, q1, q0]]
    Vall = np.concatenate(V + [neck])
    ntris = orient_outward(Vall, np.array(ntris),
                           lambda x: np.stack([np.zeros(len(x)), x[:, 1], np.full(len(x), nz)], 1))
    # Neck texture: the photo projection of the front of the neck (the back gets the front's).
    nfront = neck.copy()
    nfront[:, 2] = nz + np.abs(neck[:, 2] - nz)
    neck_uv = photo_uv(nfront)
    uv = np.concatenate([face_uv, shell_uv.reshape(-1, 2), pole_uv, neck_uv])
    tris_all = np.concatenate([face_tris, shell_tris, ntris])
    # Posing weight of every vertex: 1 turns with the head; the neck blends down to 0.2 at the
    # shoulders, which barely turn.
    wts = np.ones(len(Vall))
    lv = np.repeat(np.array([1.0, 1.0, 0.85, 0.6, 0.35, 0.2, 0.2]), m)
    wts[nbase:] = lv
    pivot = np.array([0.0, chin - 20, nz])

    # Ears: an elliptic disc on each side (56 x 28 mm), its front edge in the shell between the
    # eye line and the nose base, its back edge standing ~7 mm off the head; both faces drawn.
    # Textured by where the photo shows it; an ear the photo sees from behind (a turned photo's
    # far ear) takes the other ear's pixels, mirrored.
    y_e = 0.5 * (face_V[[33, 263], 1].mean() + face_V[2, 1])
    z_f = c[2] + 10.0
    phi_e = np.radians(15.0)
    ry, rx = 28.0, 14.0
    ke = 16
    th = np.linspace(0, 2 * np.pi, ke, endpoint=False)
    ears, ear_n = [], []
    for sgn in (-1.0, 1.0):
        q = 1 - ((y_e - c[1]) / b) ** 2 - ((z_f - c[2]) / cz) ** 2
        x_f = sgn * (a * np.sqrt(max(q, 0.05)) - 3.0)
        v_s = np.array([sgn * np.sin(phi_e), 0.0, -np.cos(phi_e)])
        u_s = np.array([0.0, 1.0, 0.0])
        ce = np.array([x_f, y_e, z_f]) + rx * v_s
        ring = ce + ry * np.sin(th)[:, None] * u_s + rx * np.cos(th)[:, None] * v_s
        nrm = np.cross(u_s, v_s)
        nrm *= np.sign(nrm[0] * sgn)
        ears.append(np.vstack([ce, ring]))
        ear_n.append(nrm)
    ebase = len(Vall)
    etris = []
    for e in range(2):
        o = ebase + e * (ke + 1)
        for k in range(ke):
            t1 = [o, o + 1 + k, o + 1 + (k + 1) % ke]
            etris += [t1, t1[::-1]]
    ears_V = np.vstack(ears)
    facing = [(R_ph @ nn)[2] for nn in ear_n]
    ear_uv = [photo_uv(ears[0]), photo_uv(ears[1])]
    for e in range(2):
        if facing[e] < 0.05 and facing[1 - e] > facing[e]:
            ear_uv[e] = ear_uv[1 - e]  # mirrored: ring k of one ear is ring k of the other
    Vall = np.concatenate([Vall, ears_V])
    uv = np.concatenate([uv, ear_uv[0], ear_uv[1]])
    tris_all = np.concatenate([tris_all, np.array(etris)])
    wts = np.concatenate([wts, np.ones(len(ears_V))])
    info = {"head_centre_mm": c.round(1).tolist(), "head_radii_mm": radii.round(1).tolist(),
            "shell_vertices": int(rings * n + 1), "neck_vertices": int(len(neck)),
            "ear_vertices": int(len(ears_V))}
    return Vall, tris_all, uv, info, wts, pivot


def pose_vertices(V, wts, pivot, pitch, yaw, roll):
    """The head turned by R(pitch, yaw, roll) about a pivot in the neck, the neck and shoulders by
    a fraction of those angles; translated so that the model origin (the centroid of the 68
    points) is where R alone puts it (R X for the face)."""
    R = rr.rot_pose_para(pitch, yaw, roll)
    out = np.empty_like(V)
    for w in np.unique(wts):
        sel = wts == w
        Rw = R if w == 1 else rr.rot_pose_para(w * pitch, w * yaw, w * roll)
        out[sel] = (V[sel] - pivot) @ Rw.T
    return out + pivot @ R.T, R


# ---------------------------------------------------------------- occlusion in the photo
def mirror_index(can_V):
    """For each canonical vertex, its mirror image (x -> -x) in the symmetric canonical mesh."""
    M = can_V * np.array([-1.0, 1.0, 1.0])
    return ((can_V[:, None] - M[None]) ** 2).sum(2).argmin(1)


def symmetric_uv(face_V, face_tris, face_uv, photo_cam, mirror):
    """Soft symmetry for the photo's blind spots (as in face frontalization): per face vertex, the
    texture coordinates of its mirror image (x -> -x) and a blending weight (0 = the photo's own
    pixels, 1 = the mirror side's). The weight is 1 where the photo does not see the vertex
    (behind the nose, beyond the far cheek's silhouette) but sees its mirror image, grows where
    the photo sees the vertex at a grazing angle and its mirror image more squarely, and is
    smoothed over the mesh so that the two textures blend without a seam. Without this, a face
    turned in the photo shows its nose again on the far cheek when the render turns it back.
    Returns (mirror uv, weights)."""
    s_ph, R_ph, t_ph = photo_cam
    Xr = face_V @ R_ph.T
    uv = np.stack([s_ph * Xr[:, 0] + t_ph[0], -(s_ph * Xr[:, 1] + t_ph[1])], 1)
    uv = uv - (uv.min(0) - 2)
    W, H = (np.ceil(uv.max(0)) + 2).astype(int)
    pix, tri, L = rr.rasterize(uv, Xr[:, 2], np.ones(len(Xr)), face_tris, int(W), int(H))
    zb = rr.zbuffer_depth(pix, tri, L, Xr[:, 2], face_tris, int(W), int(H))
    vis = rr.visible(uv, Xr[:, 2], zb, tol=2.0)  # mm
    f = rr.vertex_normals(Xr, face_tris)[:, 2]
    m = mirror
    hard = ~vis & vis[m]
    w = np.clip((f[m] - f - 0.1) / 0.4, 0, 1) * np.clip((0.55 - f) / 0.3, 0, 1)
    w = np.maximum(w, hard.astype(float))
    # smoothing over the mesh's edges
    nb = np.concatenate([face_tris[:, [0, 1]], face_tris[:, [1, 2]], face_tris[:, [2, 0]]])
    nb = np.concatenate([nb, nb[:, ::-1]])
    deg = np.bincount(nb[:, 0], minlength=len(face_V)).astype(float)
    for _ in range(4):
        acc = np.bincount(nb[:, 0], weights=w[nb[:, 1]], minlength=len(face_V))
        w = 0.5 * w + 0.5 * acc / np.maximum(deg, 1)
        w[hard] = np.maximum(w[hard], 0.9)
    return face_uv[m], w


# ---------------------------------------------------------------- identities
class Identity:
    pass


def with_mirror(uv, face_uv2, w):
    """(uv2, weights) over all head vertices: the mirror side's texture coordinates on the face,
    the own ones (weight 0) elsewhere."""
    uv2 = uv.copy()
    uv2[: len(face_uv2)] = face_uv2
    ww = np.zeros(len(uv))
    ww[: len(w)] = w
    return uv2, ww


def make_identity(name, texture, dl, fm, canonical, bfm):
    """Runs the detectors on the texture crop and builds both geometries. None if a detector
    misses the face."""
    can_V, can_T, ibug_ix = canonical
    mean, B, mu = bfm
    found = dl.landmarks(texture)
    pts = fm.landmarks(texture)
    if found is None or pts is None:
        return None
    idt = Identity()
    idt.name, idt.texture = name, texture
    idt.dlib68 = np.array(found[0], float) + 0.5  # pixel centres -> continuous coordinates
    idt.dlib5 = np.array(found[1], float) + 0.5
    mp = np.array(pts, float)
    idt.mp478 = mp[:, :2] * TEX
    face_uv = mp[:468, :2] * TEX

    # (b) bfm fit to MediaPipe's points on the photo mapped to ibug68 (the mapping of the shared
    # data): the texture coordinates are MediaPipe's points, so the fitted face lines up with its
    # texture, and the mapped jaw points are fixed vertices like bfm's (dlib's jaw follows the
    # visible contour, which biases the fit of a turned face: insightface/t1#4 came out at yaw
    # 28 from dlib's points, 42 from MediaPipe's, 46 by MediaPipe's own 3D points).
    idt.mp_ibug68 = ibug_points(idt.mp478, ibug_ix)
    X68, coef, s, R, t, rms = fit_bfm(idt.mp_ibug68, mean, B, mu)
    idt.bfm_coef, idt.bfm_rms = coef, rms
    centre = X68.mean(0)
    X68c = X68 - centre
    t = t + s * centre @ R[:2].T
    # Canonical mesh -> fitted shape: similarity on the 68 points, then a TPS through them.
    can68 = ibug_points(can_V, ibug_ix)
    ss, Rs, ts = similarity(can68, X68c)
    Vs = ss * can_V @ Rs.T + ts
    warp = tps3(ibug_points(Vs, ibug_ix), X68c, reg=2.0)
    Vb = warp(Vs)
    idt.photo_pose_b = R
    geo_b = build_head(Vb, can_T, face_uv, (s, R, t))
    mirror = mirror_index(can_V)
    uv2_b, w_b = symmetric_uv(Vb, can_T, face_uv, (s, R, t), mirror)

    # (a) MediaPipe's own 3D points: pixels, y up, z towards the camera (MediaPipe's z grows away).
    Xa = np.stack([mp[:468, 0] * TEX, -mp[:468, 1] * TEX, -mp[:468, 2] * TEX], 1)
    sa, Ra, ta = similarity(ibug_points(Xa, ibug_ix), X68c)
    Va = sa * Xa @ Ra.T + ta
    # The photo sees model point X at (x, -y) = (1/sa) Ra^T (X - ta), first two coordinates.
    Rph = Ra.T
    tph = -(ta @ Ra)[:2] / sa
    idt.photo_pose_a = Rph
    geo_a = build_head(Va, can_T, face_uv, (1 / sa, Rph, tph))
    uv2_a, w_a = symmetric_uv(Va, can_T, face_uv, (1 / sa, Rph, tph), mirror)
    idt.geometries = {
        "mediapipe": dict(V=geo_a[0], T=geo_a[1], uv=geo_a[2], info=geo_a[3], wts=geo_a[4],
                          pivot=geo_a[5], photo_cam=(1 / sa, Rph, tph),
                          sym=with_mirror(geo_a[2], uv2_a, w_a)),
        "bfm": dict(V=geo_b[0], T=geo_b[1], uv=geo_b[2], info=geo_b[3], wts=geo_b[4],
                    pivot=geo_b[5], photo_cam=(s, R, t), sym=with_mirror(geo_b[2], uv2_b, w_b)),
    }
    idt.ibug_ix = ibug_ix
    idt.iod_px = float(np.linalg.norm(idt.dlib68[36:42].mean(0) - idt.dlib68[42:48].mean(0)))
    return idt
