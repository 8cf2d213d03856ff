//! `Face` and `Pose` with their protobuf coding written out, where every other message of
//! `pose.proto` has prost's derived code: every estimate decodes a face and encodes a pose.
//!
//! - Decoding a face, prost's derive reads a packed `xy` one double per call and grows the
//!   vector as it goes, and reads each `Landmark` through a nested decode loop. Here `xy` is
//!   copied from the buffer in one pass, and a landmark's fields are read in place.
//! - Encoding a pose, it writes the packed `visible` flags one varint call each. Here they and
//!   `rotation` go out as byte slices.
//!
//! Only the plain case has a shortcut: all of the field in the buffer's current chunk, each
//! length in one byte or the usual varint, a landmark with nothing but its three fields. Anything
//! else goes to prost's own functions, from the same place in the buffer, so what is accepted,
//! what is refused and with which error are prost's. Encoding gives prost's bytes exactly.
//! The gRPC guard (`grpc/frame_guard.rs`) builds the faces of a long message with this same
//! `merge_field`, one field at a time from a slice that holds the whole field, so the shortcuts
//! apply there too.
//! The tests hold both types to prost's derived code for the same `.proto` (`facepose-protogen` writes it
//! to `generated/reference/`), on random messages and on corrupted bytes.
//!
//! The conventions a face asks for (`Face.conventions`, `Face.camera_orientation`) and their
//! answers (`Pose.conventions`) are rare and small: they go through prost's functions for
//! nested messages as they are, and a face without them costs nothing more (an empty `Vec` and
//! a `None`, no allocation).
//!
//! A field added to `Face` or `Pose` in the `.proto` must be added here. The tests build the
//! derived types field by field, so they stop compiling until it is.

use prost::bytes::{Buf, BufMut};
use prost::encoding::{
    DecodeContext, WireType, bool as pbool, decode_varint, double, encode_key, encode_varint,
    encoded_len_varint, key_len, message, skip_field, string, uint32,
};
use prost::{DecodeError, Message};

use super::{
    Camera, CameraOrientation, Convention, Conventions, ImageSize, Landmark, Translation,
    Uncertainty,
};

/// One face to estimate.
#[derive(Clone, PartialEq, Default, Debug)]
pub struct Face {
    /// The landmarks, in the order of the scheme (68 for ibug68, 51 for inner51, 5 for five).
    /// Set these or `xy`, not both.
    pub landmarks: Vec<Landmark>,
    /// The landmark scheme; empty: the one scheme with that many points.
    pub scheme: String,
    /// auto | fit | fit-shape | regression | geometry | detector; empty: auto.
    pub method: String,
    /// Optional camera intrinsics.
    pub camera: Option<Camera>,
    /// Echoed in the result. In EstimateStream it is also the face's track id for smoothing
    /// (empty: the face's index in the frame).
    pub id: String,
    /// How the landmarks were made: "projected" (empty, the default) or "contour" (2D-style).
    pub landmark_style: String,
    /// The landmarks packed, instead of `landmarks`: x0, y0, x1, y1, ... in the scheme's order.
    pub xy: Vec<f64>,
    /// With `xy`: the indices of the landmarks the client could not find, in any order.
    pub missing: Vec<u32>,
    /// The image's size: the landmarks are then normalized coordinates (MediaPipe's x, y).
    pub image_size: Option<ImageSize>,
    /// The conventions to answer in besides facepose's own (at most 4, one per name).
    pub conventions: Vec<Convention>,
    /// The camera's orientation in the world, for the conventions' answers.
    pub camera_orientation: Option<CameraOrientation>,
}

/// A pose estimate.
#[derive(Clone, PartialEq, Default, Debug)]
pub struct Pose {
    /// Yaw, degrees (Pose_Para).
    pub yaw: f64,
    /// Pitch, degrees (Pose_Para).
    pub pitch: f64,
    /// Roll, degrees (Pose_Para).
    pub roll: f64,
    /// R, 9 doubles, row-major.
    pub rotation: Vec<f64>,
    /// Per input landmark: visible at the estimated pose.
    pub visible: Vec<bool>,
    /// RMS reprojection error over the present landmarks, divided by the projected
    /// inter-ocular distance (unitless).
    pub residual: f64,
    /// The method that produced the estimate (never "auto").
    pub method: String,
    /// The scheme of the input.
    pub scheme: String,
    /// Only with camera intrinsics.
    pub translation: Option<Translation>,
    /// In EstimateStream with smoothing on: whether yaw/pitch/roll/rotation are smoothed.
    pub smoothed: bool,
    /// What the caller should know about this answer.
    pub warnings: Vec<String>,
    /// How far to trust each angle.
    pub uncertainty: Option<Uncertainty>,
    /// In EstimateStream with the Kalman filter: the frame was left out as an outlier.
    pub gated: bool,
    /// The answers in the conventions the face asked for. Boxed: they are about 350 bytes,
    /// which a pose that asks for none would otherwise carry and move.
    pub conventions: Option<Box<Conventions>>,
}

/// Names the field of a decode error, as prost's derive does.
fn in_field(message: &'static str, field: &'static str) -> impl FnOnce(DecodeError) -> DecodeError {
    move |mut e| {
        e.push(message, field);
        e
    }
}

impl Message for Face {
    fn encode_raw(&self, buf: &mut impl BufMut) {
        message::encode_repeated(1, &self.landmarks, buf);
        encode_string(2, &self.scheme, buf);
        encode_string(3, &self.method, buf);
        if let Some(c) = &self.camera {
            message::encode(4, c, buf);
        }
        encode_string(5, &self.id, buf);
        encode_string(6, &self.landmark_style, buf);
        encode_doubles(7, &self.xy, buf);
        uint32::encode_packed(8, &self.missing, buf);
        if let Some(size) = &self.image_size {
            message::encode(9, size, buf);
        }
        message::encode_repeated(10, &self.conventions, buf);
        if let Some(o) = &self.camera_orientation {
            message::encode(11, o, buf);
        }
    }

    fn merge_field(
        &mut self,
        tag: u32,
        wire_type: WireType,
        buf: &mut impl Buf,
        ctx: DecodeContext,
    ) -> Result<(), DecodeError> {
        const NAME: &str = "Face";
        match tag {
            1 => merge_landmark(wire_type, &mut self.landmarks, buf, ctx)
                .map_err(in_field(NAME, "landmarks")),
            2 => string::merge(wire_type, &mut self.scheme, buf, ctx)
                .map_err(in_field(NAME, "scheme")),
            3 => string::merge(wire_type, &mut self.method, buf, ctx)
                .map_err(in_field(NAME, "method")),
            4 => message::merge(
                wire_type,
                self.camera.get_or_insert_with(Camera::default),
                buf,
                ctx,
            )
            .map_err(in_field(NAME, "camera")),
            5 => string::merge(wire_type, &mut self.id, buf, ctx).map_err(in_field(NAME, "id")),
            6 => string::merge(wire_type, &mut self.landmark_style, buf, ctx)
                .map_err(in_field(NAME, "landmark_style")),
            7 => merge_doubles(wire_type, &mut self.xy, buf, ctx).map_err(in_field(NAME, "xy")),
            8 => uint32::merge_repeated(wire_type, &mut self.missing, buf, ctx)
                .map_err(in_field(NAME, "missing")),
            9 => message::merge(
                wire_type,
                self.image_size.get_or_insert_with(ImageSize::default),
                buf,
                ctx,
            )
            .map_err(in_field(NAME, "image_size")),
            10 => message::merge_repeated(wire_type, &mut self.conventions, buf, ctx)
                .map_err(in_field(NAME, "conventions")),
            11 => message::merge(
                wire_type,
                self.camera_orientation
                    .get_or_insert_with(CameraOrientation::default),
                buf,
                ctx,
            )
            .map_err(in_field(NAME, "camera_orientation")),
            _ => skip_field(wire_type, tag, buf, ctx),
        }
    }

    fn encoded_len(&self) -> usize {
        message::encoded_len_repeated(1, &self.landmarks)
            + string_len(2, &self.scheme)
            + string_len(3, &self.method)
            + self
                .camera
                .as_ref()
                .map_or(0, |c| message::encoded_len(4, c))
            + string_len(5, &self.id)
            + string_len(6, &self.landmark_style)
            + double::encoded_len_packed(7, &self.xy)
            + uint32::encoded_len_packed(8, &self.missing)
            + self
                .image_size
                .as_ref()
                .map_or(0, |c| message::encoded_len(9, c))
            + message::encoded_len_repeated(10, &self.conventions)
            + self
                .camera_orientation
                .as_ref()
                .map_or(0, |o| message::encoded_len(11, o))
    }

    fn clear(&mut self) {
        *self = Face::default();
    }
}

impl Message for Pose {
    fn encode_raw(&self, buf: &mut impl BufMut) {
        encode_double(1, self.yaw, buf);
        encode_double(2, self.pitch, buf);
        encode_double(3, self.roll, buf);
        encode_doubles(4, &self.rotation, buf);
        encode_bools(5, &self.visible, buf);
        encode_double(6, self.residual, buf);
        encode_string(7, &self.method, buf);
        encode_string(8, &self.scheme, buf);
        if let Some(t) = &self.translation {
            message::encode(9, t, buf);
        }
        if self.smoothed {
            pbool::encode(10, &self.smoothed, buf);
        }
        string::encode_repeated(11, &self.warnings, buf);
        if let Some(u) = &self.uncertainty {
            message::encode(12, u, buf);
        }
        if self.gated {
            pbool::encode(13, &self.gated, buf);
        }
        if let Some(c) = &self.conventions {
            message::encode(14, c, buf);
        }
    }

    fn merge_field(
        &mut self,
        tag: u32,
        wire_type: WireType,
        buf: &mut impl Buf,
        ctx: DecodeContext,
    ) -> Result<(), DecodeError> {
        const NAME: &str = "Pose";
        match tag {
            1 => double::merge(wire_type, &mut self.yaw, buf, ctx).map_err(in_field(NAME, "yaw")),
            2 => {
                double::merge(wire_type, &mut self.pitch, buf, ctx).map_err(in_field(NAME, "pitch"))
            }
            3 => double::merge(wire_type, &mut self.roll, buf, ctx).map_err(in_field(NAME, "roll")),
            4 => double::merge_repeated(wire_type, &mut self.rotation, buf, ctx)
                .map_err(in_field(NAME, "rotation")),
            5 => pbool::merge_repeated(wire_type, &mut self.visible, buf, ctx)
                .map_err(in_field(NAME, "visible")),
            6 => double::merge(wire_type, &mut self.residual, buf, ctx)
                .map_err(in_field(NAME, "residual")),
            7 => string::merge(wire_type, &mut self.method, buf, ctx)
                .map_err(in_field(NAME, "method")),
            8 => string::merge(wire_type, &mut self.scheme, buf, ctx)
                .map_err(in_field(NAME, "scheme")),
            9 => message::merge(
                wire_type,
                self.translation.get_or_insert_with(Translation::default),
                buf,
                ctx,
            )
            .map_err(in_field(NAME, "translation")),
            10 => pbool::merge(wire_type, &mut self.smoothed, buf, ctx)
                .map_err(in_field(NAME, "smoothed")),
            11 => string::merge_repeated(wire_type, &mut self.warnings, buf, ctx)
                .map_err(in_field(NAME, "warnings")),
            12 => message::merge(
                wire_type,
                self.uncertainty.get_or_insert_with(Uncertainty::default),
                buf,
                ctx,
            )
            .map_err(in_field(NAME, "uncertainty")),
            13 => {
                pbool::merge(wire_type, &mut self.gated, buf, ctx).map_err(in_field(NAME, "gated"))
            }
            14 => message::merge(
                wire_type,
                self.conventions.get_or_insert_with(Box::default).as_mut(),
                buf,
                ctx,
            )
            .map_err(in_field(NAME, "conventions")),
            _ => skip_field(wire_type, tag, buf, ctx),
        }
    }

    fn encoded_len(&self) -> usize {
        let double_len = |tag: u32, v: f64| if v != 0.0 { key_len(tag) + 8 } else { 0 };
        double_len(1, self.yaw)
            + double_len(2, self.pitch)
            + double_len(3, self.roll)
            + double::encoded_len_packed(4, &self.rotation)
            + pbool::encoded_len_packed(5, &self.visible)
            + double_len(6, self.residual)
            + string_len(7, &self.method)
            + string_len(8, &self.scheme)
            + self
                .translation
                .as_ref()
                .map_or(0, |t| message::encoded_len(9, t))
            + if self.smoothed { key_len(10) + 1 } else { 0 }
            + string::encoded_len_repeated(11, &self.warnings)
            + self
                .uncertainty
                .as_ref()
                .map_or(0, |u| message::encoded_len(12, u))
            + if self.gated { key_len(13) + 1 } else { 0 }
            + self
                .conventions
                .as_ref()
                .map_or(0, |c| message::encoded_len(14, c))
    }

    fn clear(&mut self) {
        *self = Pose::default();
    }
}

/// A proto3 string: left out when empty.
fn encode_string(tag: u32, s: &str, buf: &mut impl BufMut) {
    if !s.is_empty() {
        encode_key(tag, WireType::LengthDelimited, buf);
        encode_varint(s.len() as u64, buf);
        buf.put_slice(s.as_bytes());
    }
}

fn string_len(tag: u32, s: &str) -> usize {
    if s.is_empty() {
        0
    } else {
        key_len(tag) + encoded_len_varint(s.len() as u64) + s.len()
    }
}

/// A proto3 double: left out when zero (either sign, as prost's derive compares with `0.0`).
fn encode_double(tag: u32, v: f64, buf: &mut impl BufMut) {
    if v != 0.0 {
        double::encode(tag, &v, buf);
    }
}

/// Packed doubles, written a few at a time as bytes (prost's `encode_packed` bytes).
fn encode_doubles(tag: u32, values: &[f64], buf: &mut impl BufMut) {
    if values.is_empty() {
        return;
    }
    encode_key(tag, WireType::LengthDelimited, buf);
    encode_varint(8 * values.len() as u64, buf);
    let mut bytes = [0u8; 8 * 32];
    for part in values.chunks(32) {
        for (out, v) in bytes.chunks_exact_mut(8).zip(part) {
            out.copy_from_slice(&v.to_le_bytes());
        }
        buf.put_slice(&bytes[..8 * part.len()]);
    }
}

/// Packed bools, a byte each, written as byte slices (prost's `encode_packed` bytes).
fn encode_bools(tag: u32, values: &[bool], buf: &mut impl BufMut) {
    if values.is_empty() {
        return;
    }
    encode_key(tag, WireType::LengthDelimited, buf);
    encode_varint(values.len() as u64, buf);
    let mut bytes = [0u8; 128];
    for part in values.chunks(bytes.len()) {
        for (out, &v) in bytes.iter_mut().zip(part) {
            *out = u8::from(v);
        }
        buf.put_slice(&bytes[..part.len()]);
    }
}

/// `Face.xy`: a packed run read from the chunk in one pass when all of it is there, else
/// prost's `merge_repeated` (an unpacked value, a run split across chunks, any error).
fn merge_doubles(
    wire_type: WireType,
    values: &mut Vec<f64>,
    buf: &mut impl Buf,
    ctx: DecodeContext,
) -> Result<(), DecodeError> {
    if wire_type == WireType::LengthDelimited {
        let chunk = buf.chunk();
        let mut rest = chunk;
        if let Ok(len) = decode_varint(&mut rest)
            && let Ok(len) = usize::try_from(len)
            && len.is_multiple_of(8)
            && len <= rest.len()
        {
            let head = chunk.len() - rest.len();
            values.extend(
                rest[..len]
                    .chunks_exact(8)
                    .map(|b| f64::from_le_bytes(b.try_into().expect("eight bytes"))),
            );
            buf.advance(head + len);
            return Ok(());
        }
    }
    double::merge_repeated(wire_type, values, buf, ctx)
}

/// One `Face.landmarks` element: read in place when it is in the chunk, under 128 bytes, and
/// holds only fields 1-3 in their own wire types with `missing` as 0 or 1; else prost's
/// `message::merge_repeated`. (prost also checks its recursion limit before a nested message;
/// a landmark is three levels down at most, against a limit of 100.)
fn merge_landmark(
    wire_type: WireType,
    values: &mut Vec<Landmark>,
    buf: &mut impl Buf,
    ctx: DecodeContext,
) -> Result<(), DecodeError> {
    if wire_type == WireType::LengthDelimited
        && let Some((landmark, used)) = flat_landmark(buf.chunk())
    {
        values.push(landmark);
        buf.advance(used);
        return Ok(());
    }
    message::merge_repeated(wire_type, values, buf, ctx)
}

/// A landmark message with its one-byte length at the start of `b`, and the bytes it takes;
/// `None` unless it is of the plain kind [`merge_landmark`] reads in place.
#[inline]
fn flat_landmark(b: &[u8]) -> Option<(Landmark, usize)> {
    let (&len, rest) = b.split_first()?;
    if len >= 0x80 {
        return None;
    }
    let body = rest.get(..usize::from(len))?;
    // What every writer sends for a point that is there: x, then y.
    if let Ok(b) = <&[u8; 18]>::try_from(body)
        && b[0] == 0x09
        && b[9] == 0x11
    {
        let word = |at: usize| u64::from_le_bytes(b[at..at + 8].try_into().expect("eight bytes"));
        let landmark = Landmark {
            x: f64::from_bits(word(1)),
            y: f64::from_bits(word(10)),
            missing: false,
        };
        return Some((landmark, 19));
    }
    let mut l = Landmark::default();
    let mut i = 0;
    let double_at = |i: usize| -> Option<f64> {
        Some(f64::from_le_bytes(body.get(i + 1..i + 9)?.try_into().ok()?))
    };
    while i < body.len() {
        // Keys: field << 3 | wire type (1 = 64-bit, 0 = varint).
        match body[i] {
            0x09 => {
                l.x = double_at(i)?;
                i += 9;
            }
            0x11 => {
                l.y = double_at(i)?;
                i += 9;
            }
            0x18 => {
                l.missing = match body.get(i + 1)? {
                    0 => false,
                    1 => true,
                    _ => return None,
                };
                i += 2;
            }
            _ => return None,
        }
    }
    Some((l, 1 + usize::from(len)))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    /// prost's derived code for the same `.proto`.
    #[allow(clippy::all, missing_docs, dead_code)]
    pub(crate) mod reference {
        include!("generated/reference/facepose.v1.rs");
    }

    fn landmark(x: f64, y: f64, missing: bool) -> (Landmark, reference::Landmark) {
        (
            Landmark { x, y, missing },
            reference::Landmark { x, y, missing },
        )
    }

    /// Doubles of every kind: zeros of both signs, subnormals, infinities, NaNs.
    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            Just(0.0),
            Just(-0.0),
            -1e4..1e4f64,
            any::<u64>().prop_map(f64::from_bits),
        ]
    }

    fn text() -> impl Strategy<Value = String> {
        prop_oneof![Just(String::new()), "[a-z0-9é]{1,12}"]
    }

    /// The same message as another type of the same `.proto` message (the nested messages of
    /// the new fields are prost-derived on both sides: the pair's own code is what is tested).
    fn same<A: Message, B: Message + Default>(a: &A) -> B {
        B::decode(a.encode_to_vec().as_slice()).expect("the same message")
    }

    fn params() -> impl Strategy<Value = std::collections::BTreeMap<String, String>> {
        proptest::collection::btree_map(text(), text(), 0..4)
    }

    /// `Face.conventions`, prost's types.
    fn conventions() -> impl Strategy<Value = Vec<reference::Convention>> {
        proptest::collection::vec(
            (text(), params()).prop_map(|(name, params)| reference::Convention { name, params }),
            0..5,
        )
    }

    /// `Face.camera_orientation`, prost's types: each form, or none.
    fn orientations() -> impl Strategy<Value = Option<reference::CameraOrientation>> {
        use reference::camera_orientation::Rotation;
        let rotation = prop_oneof![
            Just(None),
            proptest::collection::vec(any_f64(), 0..11)
                .prop_map(|values| Some(Rotation::Matrix(reference::RotationMatrix { values }))),
            (any_f64(), any_f64(), any_f64(), any_f64()).prop_map(|(w, x, y, z)| Some(
                Rotation::Quaternion(reference::Quaternion { w, x, y, z })
            )),
            (params(), proptest::collection::vec(any_f64(), 0..4)).prop_map(|(params, angles)| {
                Some(Rotation::Euler(reference::EulerAngles { params, angles }))
            }),
        ];
        proptest::option::of(
            (rotation, text())
                .prop_map(|(rotation, axes)| reference::CameraOrientation { rotation, axes }),
        )
    }

    /// `Pose.conventions`, prost's types: any subset of the four answers.
    fn answers() -> impl Strategy<Value = Option<reference::Conventions>> {
        let doubles = |n: usize| proptest::collection::vec(any_f64(), 0..=n);
        let quaternion = proptest::option::of(
            (any_f64(), any_f64(), any_f64(), any_f64())
                .prop_map(|(w, x, y, z)| reference::Quaternion { w, x, y, z }),
        );
        let euler = proptest::option::of(
            (doubles(3), text(), text(), doubles(9), any::<bool>()).prop_map(
                |(angles, order, units, matrix, near_gimbal_lock)| reference::EulerConvention {
                    angles,
                    kind: order.clone(),
                    axes: units.clone(),
                    matrices: order.clone(),
                    order,
                    units,
                    matrix,
                    near_gimbal_lock,
                },
            ),
        );
        let opencv = proptest::option::of(
            (doubles(3), doubles(3), doubles(9), any::<bool>(), text()).prop_map(
                |(rvec, tvec, rotation, camera_assumed, object_frame)| {
                    reference::OpenCvConvention {
                        camera_matrix: rotation.clone(),
                        rvec,
                        tvec,
                        rotation,
                        camera_assumed,
                        object_frame,
                    }
                },
            ),
        );
        let mediapipe = proptest::option::of((doubles(16), any::<u32>(), any_f64()).prop_map(
            |(matrix, rows, fov)| reference::MediaPipeConvention {
                data: matrix.iter().rev().copied().collect(),
                matrix,
                rows,
                columns: rows / 2,
                vertical_fov_deg: fov,
            },
        ));
        proptest::option::of((quaternion, euler, opencv, mediapipe).prop_map(
            |(quaternion, euler, opencv, mediapipe)| reference::Conventions {
                quaternion,
                euler,
                opencv,
                mediapipe,
            },
        ))
    }

    prop_compose! {
        pub(crate) fn faces()(
            points in proptest::collection::vec((any_f64(), any_f64(), any::<bool>()), 0..80),
            scheme in text(), method in text(), id in text(), style in text(),
            camera in proptest::option::of((any_f64(), any_f64(), any_f64(), any_f64())),
            xy in proptest::collection::vec(any_f64(), 0..200),
            missing in proptest::collection::vec(any::<u32>(), 0..5),
            size in proptest::option::of((any_f64(), any_f64())),
            conventions in conventions(),
            orientation in orientations(),
        ) -> (Face, reference::Face) {
            let (ours, theirs): (Vec<_>, Vec<_>) =
                points.iter().map(|&(x, y, m)| landmark(x, y, m)).unzip();
            let cam = camera.map(|(fx, fy, cx, cy)| Camera { fx, fy, cx, cy });
            (
                Face {
                    landmarks: ours,
                    scheme: scheme.clone(),
                    method: method.clone(),
                    camera: cam,
                    id: id.clone(),
                    landmark_style: style.clone(),
                    xy: xy.clone(),
                    missing: missing.clone(),
                    image_size: size.map(|(width, height)| ImageSize { width, height }),
                    conventions: conventions.iter().map(same).collect(),
                    camera_orientation: orientation.as_ref().map(same),
                },
                reference::Face {
                    landmarks: theirs,
                    scheme,
                    method,
                    camera: cam.map(|c| reference::Camera { fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy }),
                    id,
                    landmark_style: style,
                    xy,
                    missing,
                    image_size: size.map(|(width, height)| reference::ImageSize { width, height }),
                    conventions,
                    camera_orientation: orientation,
                },
            )
        }
    }

    prop_compose! {
        fn poses()(
            angles in (any_f64(), any_f64(), any_f64(), any_f64()),
            rotation in proptest::collection::vec(any_f64(), 0..12),
            visible in proptest::collection::vec(any::<bool>(), 0..300),
            method in text(), scheme in text(),
            translation in proptest::option::of((any_f64(), any_f64(), any_f64())),
            smoothed in any::<bool>(),
            warnings in proptest::collection::vec(text(), 0..3),
            uncertainty in proptest::option::of(proptest::collection::vec(any_f64(), 9)),
            gated in any::<bool>(),
            answers in answers(),
        ) -> (Pose, reference::Pose) {
            let (yaw, pitch, roll, residual) = angles;
            let ours = |v: &[f64]| {
                let angle = |k: usize| super::super::AngleUncertainty {
                    sd: v[3 * k],
                    interval90: v[3 * k + 1..3 * k + 3].to_vec(),
                };
                Uncertainty { yaw: Some(angle(0)), pitch: Some(angle(1)), roll: Some(angle(2)) }
            };
            let theirs = |v: &[f64]| {
                let angle = |k: usize| reference::AngleUncertainty {
                    sd: v[3 * k],
                    interval90: v[3 * k + 1..3 * k + 3].to_vec(),
                };
                reference::Uncertainty { yaw: Some(angle(0)), pitch: Some(angle(1)), roll: Some(angle(2)) }
            };
            (
                Pose {
                    yaw, pitch, roll,
                    rotation: rotation.clone(),
                    visible: visible.clone(),
                    residual,
                    method: method.clone(),
                    scheme: scheme.clone(),
                    translation: translation.map(|(x, y, z)| Translation { x, y, z }),
                    smoothed,
                    warnings: warnings.clone(),
                    uncertainty: uncertainty.as_deref().map(ours),
                    gated,
                    conventions: answers.as_ref().map(|a| Box::new(same(a))),
                },
                reference::Pose {
                    yaw, pitch, roll, rotation, visible, residual, method, scheme,
                    translation: translation.map(|(x, y, z)| reference::Translation { x, y, z }),
                    smoothed,
                    warnings,
                    uncertainty: uncertainty.as_deref().map(theirs),
                    gated,
                    conventions: answers,
                },
            )
        }
    }

    /// Both decodings of `bytes`: equal values (compared through their encodings, which NaNs
    /// do not spoil) or both refused with the same message.
    fn same_decoding<A: Message + Default, B: Message + Default>(
        bytes: &[u8],
    ) -> Result<(), String> {
        match (A::decode(bytes), B::decode(bytes)) {
            (Ok(a), Ok(b)) if a.encode_to_vec() == b.encode_to_vec() => Ok(()),
            (Err(a), Err(b)) if a.to_string() == b.to_string() => Ok(()),
            (a, b) => Err(format!(
                "ours {:?}, prost's {:?}",
                a.map(|m| m.encode_to_vec()),
                b.map(|m| m.encode_to_vec())
            )),
        }
    }

    /// `ours` encodes to prost's bytes for `theirs`, with the same length, and decodes them back.
    fn codes_as_prost<A: Message + Default, B: Message>(
        ours: &A,
        theirs: &B,
    ) -> Result<(), TestCaseError> {
        let bytes = theirs.encode_to_vec();
        prop_assert_eq!(ours.encode_to_vec(), bytes.clone());
        prop_assert_eq!(ours.encoded_len(), theirs.encoded_len());
        prop_assert_eq!(A::decode(bytes.as_slice()).unwrap().encode_to_vec(), bytes);
        Ok(())
    }

    /// `bytes` with a few bytes changed and the end cut: the inputs a shortcut gets wrong.
    pub(crate) fn corrupted(bytes: &[u8], edits: &[(usize, u8)], cut: usize) -> Vec<u8> {
        let mut b = bytes.to_vec();
        for &(at, v) in edits {
            if !b.is_empty() {
                let at = at % b.len();
                b[at] = v;
            }
        }
        b.truncate(b.len().saturating_sub(cut));
        b
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]

        #[test]
        fn faces_code_as_prost_derives((ours, theirs) in faces()) {
            codes_as_prost(&ours, &theirs)?;
        }

        #[test]
        fn poses_code_as_prost_derives((ours, theirs) in poses()) {
            codes_as_prost(&ours, &theirs)?;
        }

        #[test]
        fn corrupted_faces_decode_as_prost_decodes_them(
            (_, theirs) in faces(),
            edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..4),
            cut in 0usize..3,
        ) {
            let bytes = corrupted(&theirs.encode_to_vec(), &edits, cut);
            let same = same_decoding::<Face, reference::Face>(&bytes);
            prop_assert!(same.is_ok(), "{:?}", same);
        }

        #[test]
        fn corrupted_poses_decode_as_prost_decodes_them(
            (_, theirs) in poses(),
            edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..4),
            cut in 0usize..3,
        ) {
            let bytes = corrupted(&theirs.encode_to_vec(), &edits, cut);
            let same = same_decoding::<Pose, reference::Pose>(&bytes);
            prop_assert!(same.is_ok(), "{:?}", same);
        }

        /// Faces inside a request, where the buffer goes on past the face: a shortcut must stop
        /// at the face's end, and a request split into chunks takes the other path.
        #[test]
        fn requests_in_chunks_decode_as_prost_decodes_them(
            (_, a) in faces(), (_, b) in faces(), split in any::<usize>(),
        ) {
            let theirs = reference::EstimateBatchRequest {
                faces: vec![a, b],
                model: "m".into(),
            };
            let bytes = theirs.encode_to_vec();
            let ours = super::super::EstimateBatchRequest::decode(bytes.as_slice()).unwrap();
            prop_assert_eq!(ours.encode_to_vec(), bytes.clone());
            let at = split % (bytes.len() + 1);
            let chained = prost::bytes::Buf::chain(&bytes[..at], &bytes[at..]);
            let ours = super::super::EstimateBatchRequest::decode(chained).unwrap();
            prop_assert_eq!(ours.encode_to_vec(), bytes);
        }
    }

    #[test]
    fn a_landmark_with_extra_or_repeated_fields_reads_as_prost_reads_it() {
        // x twice (the last one wins), then an unknown field 4: prost's path.
        let mut body = vec![0x09];
        body.extend(1.5f64.to_le_bytes());
        body.push(0x09);
        body.extend(2.5f64.to_le_bytes());
        body.extend([0x20, 0x07]);
        let mut face = vec![0x0a, body.len() as u8];
        face.extend(&body);
        same_decoding::<Face, reference::Face>(&face).unwrap();
        let decoded = Face::decode(face.as_slice()).unwrap();
        assert_eq!(
            decoded.landmarks,
            vec![Landmark {
                x: 2.5,
                y: 0.0,
                missing: false
            }]
        );
        // missing = 2 (true to prost) takes prost's path too.
        let face = [0x0a, 0x02, 0x18, 0x02];
        same_decoding::<Face, reference::Face>(&face).unwrap();
        assert!(Face::decode(face.as_slice()).unwrap().landmarks[0].missing);
    }

    #[test]
    fn unpacked_doubles_are_read_too() {
        // xy = [1.0, 2.0] as two unpacked fields (wire type 1), as proto2 writers may send.
        let mut bytes = vec![0x39];
        bytes.extend(1.0f64.to_le_bytes());
        bytes.push(0x39);
        bytes.extend(2.0f64.to_le_bytes());
        assert_eq!(Face::decode(bytes.as_slice()).unwrap().xy, vec![1.0, 2.0]);
        same_decoding::<Face, reference::Face>(&bytes).unwrap();
    }

    #[test]
    fn malformed_packed_doubles_are_refused_as_prost_refuses_them() {
        let run = |len: u8, payload: usize| {
            let mut bytes = vec![0x3a, len];
            bytes.extend(std::iter::repeat_n(0x40, payload));
            same_decoding::<Face, reference::Face>(&bytes).unwrap();
            Face::decode(bytes.as_slice())
        };
        assert!(run(7, 7).is_err(), "a length that is not whole doubles");
        assert!(run(16, 8).is_err(), "a length past the end");
        assert_eq!(
            run(16, 16).unwrap().xy,
            vec![f64::from_bits(0x4040_4040_4040_4040); 2]
        );
        // A length varint that does not end within the message.
        same_decoding::<Face, reference::Face>(&[0x3a, 0x80]).unwrap();
        assert!(Face::decode([0x3a, 0x80].as_slice()).is_err());
    }
}
