"""Runs two real landmark detectors on real photographs and on copies whose true pose change is
known, and writes what they found as test fixtures (tests/fixtures/detectors/, read by
tests/integration/detectors.rs and scripts/detector_report.py). Run by
scripts/detector-landmarks.sh, which makes the virtual environment.

- dlib 20: `get_frontal_face_detector`, then the 68-point (ibug68) and 5-point (dlib5)
  predictors of face-recognition-models; pixels. -> dlib.json
- MediaPipe 0.10.14: `mediapipe.solutions.face_mesh.FaceMesh(static_image_mode=True,
  refine_landmarks=True)`, its model bundled in the wheel; 478 points (468 mesh + 10 iris)
  normalized by the image width and height, as MediaPipe gives them (`z` is left out: the
  service does not take it). Beside them, MediaPipe's facial transformation matrix, made by
  MediaPipe's own face-geometry calculator (see `FaceGeometry`). -> mediapipe.json

The photographs are those of scikit-image: `data.astronaut()` (512x512, colour) with a mirrored,
rotated, scaled and cropped copy, and the first faces of `data.lfw_subset()` (25x25 grey crops
of Labeled Faces in the Wild, upscaled 8x so that the detectors find them). `data.camera()`
also shows a face, but a small one in profile behind a camera: neither detector finds it.
scikit-image has no other photograph of a person.

Prints, per image, how far each of dlib's five points lies from the ibug68 point that scheme
dlib5 maps it to (DLIB5_IN_IBUG68 in crates/core/src/shape/scheme.rs), and MediaPipe's matrix.
"""

import json
import os
import sys

import dlib
import face_recognition_models as models
import mediapipe as mp
import numpy as np
from mediapipe.framework import calculator_pb2
from mediapipe.framework.formats import landmark_pb2
from mediapipe.python import packet_creator, packet_getter
from mediapipe.tasks.cc.vision.face_geometry.calculators import (
    geometry_pipeline_calculator_pb2 as geometry_calculator,
)
from mediapipe.tasks.cc.vision.face_geometry.proto import (
    environment_pb2,
    face_geometry_pb2,  # noqa: F401 (registers the output's message type for get_proto)
    geometry_pipeline_metadata_pb2 as metadata_pb2,
    mesh_3d_pb2,
)
from skimage import data, transform

DLIB5_IN_IBUG68 = [45, 42, 36, 39, 33]
# In-plane rotations of the astronaut, degrees anticlockwise on screen (skimage's sense).
ROTATIONS = (20, -20, 40, -40)
# Faces of data.lfw_subset() (its first 100 images are faces): the first ones, none skipped.
LFW_FACES = 3
LFW_UPSCALE = 8
DECIMALS = 5


def astronaut_copies():
    """(name, image, what the transform does to the pose) for the astronaut and its copies."""
    img = data.astronaut()
    h, w = img.shape[:2]
    yield "astronaut/original", img, "none"
    yield "astronaut/mirrored", img[:, ::-1].copy(), "mirror: yaw and roll change sign"
    for deg in ROTATIONS:
        # skimage rotates counter-clockwise on screen for a positive angle: the face turns
        # anticlockwise, so roll (clockwise positive) changes by -deg.
        rot = transform.rotate(img, deg, resize=True, preserve_range=True).astype(np.uint8)
        yield f"astronaut/rotated{deg:+d}", rot, f"roll changes by {-deg}"
    small = transform.rescale(img, 0.6, channel_axis=2, preserve_range=True).astype(np.uint8)
    yield "astronaut/scaled0.6", small, "none"
    yield "astronaut/cropped", img[40 : h - 100, 60 : w - 40].copy(), "none"


def lfw_faces():
    faces = data.lfw_subset()[:LFW_FACES]
    for k, grey in enumerate(faces):
        size = grey.shape[0] * LFW_UPSCALE
        big = transform.resize(grey, (size, size), order=3)
        rgb = np.repeat((np.clip(big, 0, 1) * 255).round().astype(np.uint8)[:, :, None], 3, 2)
        yield f"lfw_subset/{k}", rgb, f"another face (25x25 px, upscaled {LFW_UPSCALE}x)"


class Dlib:
    def __init__(self):
        self.detector = dlib.get_frontal_face_detector()
        self.p68 = dlib.shape_predictor(models.pose_predictor_model_location())
        self.p5 = dlib.shape_predictor(models.pose_predictor_five_point_model_location())

    def landmarks(self, img):
        """(ibug68, dlib5) pixels of the best-scoring face, or None."""
        rects, scores, _ = self.detector.run(img, 1, 0.0)
        if not rects:
            return None
        r = rects[int(np.argmax(scores))]
        a = [[p.x, p.y] for p in self.p68(img, r).parts()]
        b = [[p.x, p.y] for p in self.p5(img, r).parts()]
        return a, b


class FaceMesh:
    """MediaPipe's legacy Face Mesh solution, whose model ships in the wheel."""

    def __init__(self):
        self.mesh = mp.solutions.face_mesh.FaceMesh(
            static_image_mode=True, refine_landmarks=True, max_num_faces=1
        )

    def landmarks(self, img):
        """478 [x, y, z] (x, y normalized by width and height), or None."""
        r = self.mesh.process(img)
        if not r.multi_face_landmarks:
            return None
        return [[p.x, p.y, p.z] for p in r.multi_face_landmarks[0].landmark]


class FaceGeometry:
    """MediaPipe's facial transformation matrix for given landmarks, computed by MediaPipe's own
    `FaceGeometryPipelineCalculator`, the calculator that the Tasks FaceLandmarker runs for
    `output_facial_transformation_matrixes=True` (registered in the wheel's framework library).

    The Tasks API itself needs a `face_landmarker.task` bundle, which the wheel does not ship;
    the calculator needs only what that bundle adds for it, the geometry metadata (the canonical
    face mesh and the Procrustes landmark weights). That metadata is rebuilt here from
    canonical_face_468.json of the shared data, which holds the same mesh (mm; MediaPipe's is in
    cm, so divided by 10) and the same 33 weights; its texture coordinates are not in the file
    and are set to 0 (they do not enter the pose). The environment is FaceLandmarker's default
    (origin top-left, a perspective camera with a vertical field of view of 63°, near 1 cm,
    far 100 m), and the landmarks are the first 468, as FaceLandmarker passes them.

    The matrix maps the canonical face (x right, y up, z towards the viewer, cm) into a metric
    camera space (x right, y up, z towards the viewer, the camera at the origin looking down
    -z): its upper 3x3 is a rotation, its last column the face's position in cm.
    """

    def __init__(self, canonical_path):
        with open(canonical_path) as f:
            canonical = json.load(f)
        md = metadata_pb2.GeometryPipelineMetadata()
        md.input_source = metadata_pb2.FACE_LANDMARK_PIPELINE
        md.canonical_mesh.vertex_type = mesh_3d_pb2.Mesh3d.VERTEX_PT
        md.canonical_mesh.primitive_type = mesh_3d_pb2.Mesh3d.TRIANGLE
        for v in canonical["vertices"]:
            md.canonical_mesh.vertex_buffer.extend([v[0] / 10, v[1] / 10, v[2] / 10, 0.0, 0.0])
        for t in canonical["triangles"]:
            md.canonical_mesh.index_buffer.extend(t)
        for i, w in canonical["procrustes_landmark_weights"]:
            ref = md.procrustes_landmark_basis.add()
            ref.landmark_id = i
            ref.weight = w

        cfg = calculator_pb2.CalculatorGraphConfig()
        cfg.input_stream.extend(["image", "landmarks"])
        cfg.input_side_packet.append("environment")
        cfg.output_stream.append("geometry")
        size = cfg.node.add()
        size.calculator = "ImagePropertiesCalculator"
        size.input_stream.append("IMAGE:image")
        size.output_stream.append("SIZE:size")
        node = cfg.node.add()
        node.calculator = "mediapipe.tasks.vision.face_geometry.FaceGeometryPipelineCalculator"
        node.input_stream.extend(["IMAGE_SIZE:size", "FACE_LANDMARKS:landmarks"])
        node.input_side_packet.append("ENVIRONMENT:environment")
        node.output_stream.append("FACE_GEOMETRY:geometry")
        opts = node.options.Extensions[geometry_calculator.FaceGeometryPipelineCalculatorOptions.ext]
        opts.metadata_file.file_content = md.SerializeToString()

        env = environment_pb2.Environment()
        env.origin_point_location = environment_pb2.TOP_LEFT_CORNER
        env.perspective_camera.vertical_fov_degrees = 63.0
        env.perspective_camera.near = 1.0
        env.perspective_camera.far = 10000.0

        self.out = []
        self.graph = mp.CalculatorGraph(graph_config=cfg)
        self.graph.observe_output_stream(
            "geometry", lambda _, p: self.out.append(packet_getter.get_proto(p))
        )
        self.graph.start_run(input_side_packets={"environment": packet_creator.create_proto(env)})
        self.t = 0

    def matrix(self, img, points):
        """The 4x4 matrix (row-major) for 478 normalized points found on `img`."""
        lms = landmark_pb2.NormalizedLandmarkList()
        for x, y, z in points[:468]:
            p = lms.landmark.add()
            p.x, p.y, p.z = x, y, z
        frame = packet_creator.create_image_frame(image_format=mp.ImageFormat.SRGB, data=img)
        self.graph.add_packet_to_input_stream("image", frame.at(self.t))
        self.graph.add_packet_to_input_stream(
            "landmarks", packet_creator.create_proto(lms).at(self.t)
        )
        self.t += 1
        self.graph.wait_until_idle()
        m = self.out.pop().pose_transform_matrix
        a = np.array(m.packed_data, dtype=float).reshape(m.cols, m.rows)
        # MatrixData's default layout is column-major: each row of `a` is a column.
        return a if m.layout == m.Layout.ROW_MAJOR else a.T

    def close(self):
        self.graph.close()


def rounded(rows, decimals=DECIMALS):
    return [[round(float(v), decimals) for v in row] for row in rows]


def write(path, doc, points_key):
    """JSON with one point per line: small, and readable in a diff."""
    lines = ["{"]
    for k, v in doc.items():
        if k != "faces":
            lines.append(f" {json.dumps(k)}: {json.dumps(v)},")
    lines.append(' "faces": [')
    for i, face in enumerate(doc["faces"]):
        lines.append("  {")
        items = list(face.items())
        for j, (k, v) in enumerate(items):
            end = "," if j + 1 < len(items) else ""
            if k in points_key:
                rows = ",\n    ".join(json.dumps(p, separators=(",", ":")) for p in v)
                lines.append(f"   {json.dumps(k)}: [\n    {rows}\n   ]{end}")
            else:
                lines.append(f"   {json.dumps(k)}: {json.dumps(v)}{end}")
        lines.append("  }" + ("," if i + 1 < len(doc["faces"]) else ""))
    lines.append(" ]")
    lines.append("}")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    print(f"wrote {path}")


def main(out_dir, canonical_path):
    dl, mesh, geometry = Dlib(), FaceMesh(), FaceGeometry(canonical_path)
    dlib_faces, mp_faces = [], []
    images = list(astronaut_copies()) + list(lfw_faces())
    for name, img, change in images:
        size = [img.shape[1], img.shape[0]]
        found = dl.landmarks(img)
        points = mesh.landmarks(img)
        if found is None or points is None:
            sys.exit(f"{name}: no face found by {'dlib' if found is None else 'MediaPipe'}")
        a, b = found
        dist = [float(np.hypot(*np.subtract(b[k], a[i]))) for k, i in enumerate(DLIB5_IN_IBUG68)]
        m = geometry.matrix(img, points)
        print(
            f"{name:20s} {size[0]}x{size[1]}  dlib5 point to its ibug68 point, px: "
            + " ".join(f"{d:.1f}" for d in dist)
            + "\n    MediaPipe's matrix: "
            + "; ".join(" ".join(f"{v:+.4f}" for v in row) for row in m[:3])
        )
        dlib_faces.append(
            {"image": name, "transform": change, "image_size": size, "ibug68": a, "dlib5": b}
        )
        mp_faces.append(
            {
                "image": name,
                "transform": change,
                "image_size": size,
                "facial_transformation_matrix": rounded(m),
                "landmarks": rounded([p[:2] for p in points]),
            }
        )
    geometry.close()
    photos = (
        "scikit-image data.astronaut() and copies of it (mirrored, turned by"
        f" {', '.join(f'{d:+d}' for d in ROTATIONS)} degrees anticlockwise, scaled 0.6, cropped);"
        f" the first {LFW_FACES} faces of data.lfw_subset(), upscaled {LFW_UPSCALE}x"
    )
    made_by = "scripts/detector-landmarks.sh"
    write(
        os.path.join(out_dir, "dlib.json"),
        {
            "photos": photos,
            "detector": f"dlib {dlib.__version__}: get_frontal_face_detector, then"
            " shape_predictor_68_face_landmarks and shape_predictor_5_face_landmarks"
            " (face-recognition-models)",
            "points": "ibug68 and dlib5, pixels",
            "made_by": made_by,
            "faces": dlib_faces,
        },
        ("ibug68", "dlib5"),
    )
    write(
        os.path.join(out_dir, "mediapipe.json"),
        {
            "photos": photos,
            "detector": f"MediaPipe {mp.__version__}: solutions.face_mesh.FaceMesh("
            "static_image_mode=True, refine_landmarks=True)",
            "points": "478 [x, y] (468 mesh points, then 10 iris points) normalized by the image"
            " width and height, as MediaPipe gives them; z left out",
            "facial_transformation_matrix": "4x4, row-major: MediaPipe's own"
            " FaceGeometryPipelineCalculator (what FaceLandmarker returns as"
            " facial_transformation_matrixes) on the first 468 landmarks, with FaceLandmarker's"
            " default environment (vertical field of view 63 degrees) and its geometry metadata"
            " rebuilt from the shared canonical_face_468.json; canonical face (x right, y up,"
            " z towards the viewer, cm) -> camera space (the same axes; camera at the origin"
            " looking down -z), translation in cm",
            "made_by": made_by,
            "faces": mp_faces,
        },
        ("landmarks",),
    )

if __name__ == "__main__":
    main(
        sys.argv[1] if len(sys.argv) > 1 else "tests/fixtures/detectors",
        sys.argv[2] if len(sys.argv) > 2 else "../shared/data/mediapipe/canonical_face_468.json",
    )
