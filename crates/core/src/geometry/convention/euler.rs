//! Euler angles in any convention a caller can name: an axis order (the twelve sequences,
//! Tait-Bryan `XYZ` ... and proper `ZXZ` ...), intrinsic or extrinsic, degrees or radians, the
//! axes the angles turn about ([`Axes`]) and the sense of the elementary matrices
//! ([`Matrices`]).
//!
//! Why these parameters: a set of three numbers is a rotation only once all five are fixed,
//! and the tools that report head pose differ in every one of them.
//!
//! | tool | order | kind | units | axes | matrices |
//! | --- | --- | --- | --- | --- | --- |
//! | 300W-LP / AFLW2000-3D `Pose_Para`, Hopenet, FSA-Net, 6DRepNet (facepose's `angles`) | `XYZ` | intrinsic | degrees | `RUB` | `pose-para` |
//! | OpenFace `pose_Rx, pose_Ry, pose_Rz` | `XYZ` | intrinsic | radians | `RDF` | `standard` |
//! | three.js `Euler` (default order) | `XYZ` | intrinsic | radians | `RUB` | `standard` |
//! | Unity `Transform.eulerAngles` (z, then x, then y about fixed axes) | `YXZ` (= `zxy` extrinsic) | intrinsic | degrees | `RUF` (left-handed) | `standard` |
//! | scipy `Rotation.as_euler(seq)` | `seq` | upper case intrinsic, lower case extrinsic | either | the caller's | `standard` |
//!
//! **Order and kind.** `order` is three axis letters, no two neighbours equal. As in scipy, upper
//! case is intrinsic (each turn about the axes as already turned: `XYZ` with angles `(a, b, c)`
//! is `R = Rx(a) Ry(b) Rz(c)`) and lower case extrinsic (about the fixed axes, the first letter
//! first: `xyz` is `R = Rz(c) Ry(b) Rx(a)`). `xyz` extrinsic with `(a, b, c)` is `ZYX`
//! intrinsic with `(c, b, a)`.
//!
//! **Axes.** Three letters, one per axis x, y, z, each the direction that axis points in the
//! camera's view: `R`ight/`L`eft, `U`p/`D`own, `B`ack (towards the viewer)/`F`orward (away from
//! the viewer, into the scene). facepose's frames are `RUB` (as OpenGL and three.js); OpenCV's
//! camera is `RDF`; Unity's `RUF` is left-handed. The rotation is expressed in those axes by
//! conjugation, `R' = A R Aᵀ` with `A`'s rows the new axes in facepose's frame: the head's frame
//! and the camera's (or world's) frame both take the new axes, so a face looking straight at the
//! camera is the identity in every choice (facepose's model frame at identity faces the camera).
//!
//! **Matrices.** `standard`: `Rx(a) = [[1,0,0],[0,c,-s],[0,s,c]]` and likewise (scipy, three.js,
//! Unity, OpenCV; in a right-handed frame a positive angle turns anticlockwise seen from the
//! axis' tip, in Unity's left-handed frame clockwise, as Unity documents). `pose-para`: their
//! transposes, `Rx(a) = [[1,0,0],[0,c,s],[0,-s,c]]`, as `Pose_Para` writes them (the same as
//! `standard` with every angle negated).
//!
//! **Ranges.** Tait-Bryan: the middle angle in [-90°, 90°], the others in (-180°, 180°]. Proper
//! Euler: the middle angle in [0°, 180°]. Unity shows its angles modulo 360.
//!
//! **Gimbal lock.** Where the middle angle is ±90° (Tait-Bryan) or 0°/180° (proper), the first
//! and third turns are about the same axis and only their sum (or difference) is defined. As
//! scipy does, the decomposition then sets the third angle (the order's last letter, intrinsic
//! or extrinsic) to 0 and puts the whole turn in the first. The angles always rebuild the matrix;
//! near the lock they are ill-conditioned: a change of the matrix by ε moves the first and third
//! angles by up to about ε / cos(middle) (Tait-Bryan; ε / sin(middle) proper), while the matrix
//! and the quaternion stay well-conditioned everywhere. The answer says when the middle angle is
//! within 1° of the lock (`near_gimbal_lock`).
//!
//! With `pose-para` matrices the angles are the negated `standard` ones; for a proper order the
//! middle angle is then brought back into [0°, 180°] (`(a, b, c) ≡ (a + 180°, -b, c + 180°)`).

use std::fmt;
use std::str::FromStr;

use nalgebra::{Matrix3, Vector3};

use super::request::ConventionError;

/// One of the three coordinate axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Axis {
    /// The x axis.
    X = 0,
    /// The y axis.
    Y = 1,
    /// The z axis.
    Z = 2,
}

impl Axis {
    fn index(self) -> usize {
        self as usize
    }

    fn letter(self) -> char {
        ['x', 'y', 'z'][self.index()]
    }

    fn of(c: char) -> Option<Axis> {
        match c.to_ascii_lowercase() {
            'x' => Some(Axis::X),
            'y' => Some(Axis::Y),
            'z' => Some(Axis::Z),
            _ => None,
        }
    }
}

/// The standard (right-hand rule in a right-handed frame) rotation about `axis` by `rad`.
pub fn standard_rotation(axis: Axis, rad: f64) -> Matrix3<f64> {
    let (s, c) = rad.sin_cos();
    match axis {
        Axis::X => Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c),
        Axis::Y => Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c),
        Axis::Z => Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0),
    }
}

/// Intrinsic (each turn about the turned axes) or extrinsic (about the fixed axes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    /// Each turn about the axes as turned by the previous ones.
    Intrinsic,
    /// Each turn about the fixed axes.
    Extrinsic,
}

impl Kind {
    /// The names, as requests write them.
    pub const NAMES: [&'static str; 2] = ["intrinsic", "extrinsic"];

    /// The name, as requests write it.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Intrinsic => "intrinsic",
            Kind::Extrinsic => "extrinsic",
        }
    }
}

/// An axis sequence: three axes, no two neighbours equal (six Tait-Bryan, six proper Euler).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Order(pub [Axis; 3]);

impl Order {
    /// Parses three letters from `xyz` (either case). Returns the order and the kind its case
    /// says (upper intrinsic, lower extrinsic; mixed case is an error).
    pub fn parse(s: &str) -> Result<(Order, Kind), ConventionError> {
        let bad = |reason: &str| ConventionError::BadOrder {
            order: s.to_string(),
            reason: reason.to_string(),
        };
        let chars: Vec<char> = s.chars().collect();
        if chars.len() != 3 {
            return Err(bad("an order is three axis letters, e.g. XYZ, zyx or ZXZ"));
        }
        let mut axes = [Axis::X; 3];
        for (k, c) in chars.iter().enumerate() {
            axes[k] = Axis::of(*c).ok_or_else(|| bad("the letters must be x, y or z"))?;
        }
        if axes[0] == axes[1] || axes[1] == axes[2] {
            return Err(bad(
                "two neighbouring turns about the same axis are one turn: \
                 use three distinct axes (XYZ) or the first repeated last (ZXZ)",
            ));
        }
        let kind = if chars.iter().all(|c| c.is_ascii_uppercase()) {
            Kind::Intrinsic
        } else if chars.iter().all(|c| c.is_ascii_lowercase()) {
            Kind::Extrinsic
        } else {
            return Err(bad(
                "mixed case: upper case is intrinsic (XYZ), lower case extrinsic (xyz), as in scipy",
            ));
        };
        Ok((Order(axes), kind))
    }

    /// Three distinct axes (Tait-Bryan) rather than the first repeated (proper Euler).
    pub fn is_tait_bryan(self) -> bool {
        self.0[0] != self.0[2]
    }

    /// The order written in the case of `kind` (upper intrinsic, lower extrinsic).
    pub fn written(self, kind: Kind) -> String {
        self.0
            .iter()
            .map(|a| match kind {
                Kind::Intrinsic => a.letter().to_ascii_uppercase(),
                Kind::Extrinsic => a.letter(),
            })
            .collect()
    }

    fn reversed(self) -> Order {
        Order([self.0[2], self.0[1], self.0[0]])
    }
}

/// Degrees or radians.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Units {
    /// Angles in degrees.
    Degrees,
    /// Angles in radians.
    Radians,
}

impl Units {
    /// The names, as requests write them.
    pub const NAMES: [&'static str; 2] = ["degrees", "radians"];

    /// The name, as requests write it.
    pub fn name(self) -> &'static str {
        match self {
            Units::Degrees => "degrees",
            Units::Radians => "radians",
        }
    }

    fn of_rad(self, r: f64) -> f64 {
        match self {
            Units::Degrees => r.to_degrees(),
            Units::Radians => r,
        }
    }

    fn to_rad(self, a: f64) -> f64 {
        match self {
            Units::Degrees => a.to_radians(),
            Units::Radians => a,
        }
    }
}

impl FromStr for Units {
    type Err = ();
    fn from_str(s: &str) -> Result<Self, ()> {
        match s.to_ascii_lowercase().as_str() {
            "degrees" | "degree" | "deg" => Ok(Units::Degrees),
            "radians" | "radian" | "rad" => Ok(Units::Radians),
            _ => Err(()),
        }
    }
}

/// The sense of the elementary rotation matrices (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Matrices {
    /// `Rx(a) = [[1,0,0],[0,c,-s],[0,s,c]]`, ... (scipy, three.js, Unity, OpenCV).
    Standard,
    /// The transposes, as `Pose_Para` writes them.
    PosePara,
}

impl Matrices {
    /// The names, as requests write them.
    pub const NAMES: [&'static str; 2] = ["standard", "pose-para"];

    /// The name, as requests write it.
    pub fn name(self) -> &'static str {
        match self {
            Matrices::Standard => "standard",
            Matrices::PosePara => "pose-para",
        }
    }
}

/// The axes the angles turn about, as the directions x, y, z point in the camera's view (see
/// the module docs): facepose's own frames are `RUB`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Axes([Direction; 3]);

/// A direction in the camera's view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Towards the image's right.
    Right,
    /// Towards the image's left.
    Left,
    /// Towards the image's top.
    Up,
    /// Towards the image's bottom.
    Down,
    /// Towards the viewer (facepose's +z).
    Back,
    /// Away from the viewer, into the scene.
    Forward,
}

impl Direction {
    fn letter(self) -> char {
        match self {
            Direction::Right => 'R',
            Direction::Left => 'L',
            Direction::Up => 'U',
            Direction::Down => 'D',
            Direction::Back => 'B',
            Direction::Forward => 'F',
        }
    }

    fn of(c: char) -> Option<Direction> {
        Some(match c.to_ascii_uppercase() {
            'R' => Direction::Right,
            'L' => Direction::Left,
            'U' => Direction::Up,
            'D' => Direction::Down,
            'B' => Direction::Back,
            'F' => Direction::Forward,
            _ => return None,
        })
    }

    /// The direction in facepose's frame (x right, y up, z back).
    fn vector(self) -> Vector3<f64> {
        match self {
            Direction::Right => Vector3::x(),
            Direction::Left => -Vector3::x(),
            Direction::Up => Vector3::y(),
            Direction::Down => -Vector3::y(),
            Direction::Back => Vector3::z(),
            Direction::Forward => -Vector3::z(),
        }
    }
}

impl Axes {
    /// facepose's frames, OpenGL's and three.js's: x right, y up, z back.
    pub const FACEPOSE: Axes = Axes([Direction::Right, Direction::Up, Direction::Back]);
    /// OpenCV's camera (and OpenFace's): x right, y down, z forward.
    pub const OPENCV: Axes = Axes([Direction::Right, Direction::Down, Direction::Forward]);
    /// Unity's: x right, y up, z forward (left-handed).
    pub const UNITY: Axes = Axes([Direction::Right, Direction::Up, Direction::Forward]);

    /// Names that stand for a triple.
    pub const ALIASES: [(&'static str, Axes); 5] = [
        ("facepose", Axes::FACEPOSE),
        ("opengl", Axes::FACEPOSE),
        ("three", Axes::FACEPOSE),
        ("opencv", Axes::OPENCV),
        ("unity", Axes::UNITY),
    ];

    /// Parses three direction letters (`RUB`, `rdf`, ...) or an alias.
    pub fn parse(s: &str) -> Result<Axes, ConventionError> {
        if let Some((_, a)) = Axes::ALIASES
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(s))
        {
            return Ok(*a);
        }
        let bad = || ConventionError::BadValue {
            convention: "euler".into(),
            param: "axes".into(),
            value: s.into(),
            expected: "three letters giving the direction of x, y and z in the camera's view, \
                       one each of R/L (right, left), U/D (up, down), B/F (back towards the \
                       viewer, forward into the scene), e.g. RUB (facepose, OpenGL, three.js), \
                       RDF (OpenCV, OpenFace), RUF (Unity); or one of facepose, opengl, three, \
                       opencv, unity"
                .into(),
        };
        let chars: Vec<char> = s.chars().collect();
        if chars.len() != 3 {
            return Err(bad());
        }
        let mut d = [Direction::Right; 3];
        for (k, c) in chars.iter().enumerate() {
            d[k] = Direction::of(*c).ok_or_else(bad)?;
        }
        let m = Axes(d).matrix();
        if (m.determinant().abs() - 1.0).abs() > 1e-12 {
            return Err(bad());
        }
        Ok(Axes(d))
    }

    /// `A`: rows are the axes in facepose's frame, so that `A v` are a vector's coordinates.
    pub fn matrix(self) -> Matrix3<f64> {
        Matrix3::from_rows(&self.0.map(|d| d.vector().transpose()))
    }

    /// Whether the triple is right-handed.
    pub fn is_right_handed(self) -> bool {
        self.matrix().determinant() > 0.0
    }

    /// The three letters.
    pub fn letters(self) -> String {
        self.0.iter().map(|d| d.letter()).collect()
    }

    /// `A R Aᵀ`: facepose's rotation expressed in these axes.
    pub fn express(self, r: &Matrix3<f64>) -> Matrix3<f64> {
        let a = self.matrix();
        a * r * a.transpose()
    }

    /// `Aᵀ R' A`: back to facepose's axes.
    pub fn unexpress(self, r: &Matrix3<f64>) -> Matrix3<f64> {
        let a = self.matrix();
        a.transpose() * r * a
    }
}

impl fmt::Display for Axes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.letters())
    }
}

/// A complete Euler convention.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct EulerSpec {
    /// The axes' order of the turns.
    pub order: Order,
    /// Intrinsic or extrinsic turns.
    pub kind: Kind,
    /// Degrees or radians.
    pub units: Units,
    /// The directions the x, y, z axes point in the camera's view.
    pub axes: Axes,
    /// The sense of the elementary rotation matrices.
    pub matrices: Matrices,
}

/// Named conventions of the tools that report head pose.
pub const PRESETS: [(&str, EulerSpec); 6] = [
    ("pose-para", EulerSpec::POSE_PARA),
    ("6drepnet", EulerSpec::POSE_PARA),
    ("hopenet", EulerSpec::POSE_PARA),
    ("openface", EulerSpec::OPENFACE),
    ("three", EulerSpec::THREE),
    ("unity", EulerSpec::UNITY),
];

impl EulerSpec {
    /// 300W-LP / AFLW2000-3D `Pose_Para` (Hopenet, FSA-Net, 6DRepNet): [pitch, yaw, roll] in
    /// degrees, facepose's own `angles`.
    pub const POSE_PARA: EulerSpec = EulerSpec {
        order: Order([Axis::X, Axis::Y, Axis::Z]),
        kind: Kind::Intrinsic,
        units: Units::Degrees,
        axes: Axes::FACEPOSE,
        matrices: Matrices::PosePara,
    };
    /// OpenFace's `pose_Rx, pose_Ry, pose_Rz`: `R = Rx Ry Rz` in OpenCV's axes, radians.
    pub const OPENFACE: EulerSpec = EulerSpec {
        order: Order([Axis::X, Axis::Y, Axis::Z]),
        kind: Kind::Intrinsic,
        units: Units::Radians,
        axes: Axes::OPENCV,
        matrices: Matrices::Standard,
    };
    /// three.js `Euler` with its default order `'XYZ'`, radians.
    pub const THREE: EulerSpec = EulerSpec {
        order: Order([Axis::X, Axis::Y, Axis::Z]),
        kind: Kind::Intrinsic,
        units: Units::Radians,
        axes: Axes::FACEPOSE,
        matrices: Matrices::Standard,
    };
    /// Unity's `eulerAngles` (x, y, z): z first, then x, then y about the fixed axes, degrees,
    /// left-handed axes. Angles are listed in the order's letters: [y, x, z].
    pub const UNITY: EulerSpec = EulerSpec {
        order: Order([Axis::Y, Axis::X, Axis::Z]),
        kind: Kind::Intrinsic,
        units: Units::Degrees,
        axes: Axes::UNITY,
        matrices: Matrices::Standard,
    };

    /// The angles (in the order's letters) of facepose's rotation `r` (facepose's axes).
    pub fn angles(&self, r: &Matrix3<f64>) -> [f64; 3] {
        let m = self.axes.express(r);
        // Pose-para matrices are the standard ones with the angles negated.
        let sign = match self.matrices {
            Matrices::Standard => 1.0,
            Matrices::PosePara => -1.0,
        };
        let rad = match self.kind {
            Kind::Intrinsic => intrinsic_angles(&m, self.order),
            Kind::Extrinsic => {
                let [a, b, c] = intrinsic_angles_lock_first(&m, self.order.reversed());
                [c, b, a]
            }
        };
        let mut rad = rad.map(|a| sign * a);
        if !self.order.is_tait_bryan() && rad[1] < 0.0 {
            // E_j(-b) with b = 180° is E_j(180°): only the sign changes at the lock.
            if rad[1].sin().abs() > LOCK {
                rad[0] = wrap_pi(rad[0] + std::f64::consts::PI);
                rad[2] = wrap_pi(rad[2] + std::f64::consts::PI);
            }
            rad[1] = -rad[1];
        }
        rad[0] = wrap_pi(rad[0]);
        rad[2] = wrap_pi(rad[2]);
        rad.map(|a| self.units.of_rad(a) + 0.0)
    }

    /// The rotation, in facepose's axes, of angles given in this convention.
    pub fn rotation(&self, angles: [f64; 3]) -> Matrix3<f64> {
        self.axes.unexpress(&self.matrix_in_axes(angles))
    }

    /// The matrix the angles rebuild in this convention's own axes (`A R Aᵀ`).
    pub fn matrix_in_axes(&self, angles: [f64; 3]) -> Matrix3<f64> {
        let sign = match self.matrices {
            Matrices::Standard => 1.0,
            Matrices::PosePara => -1.0,
        };
        let e = |k: usize| standard_rotation(self.order.0[k], sign * self.units.to_rad(angles[k]));
        match self.kind {
            Kind::Intrinsic => e(0) * e(1) * e(2),
            Kind::Extrinsic => e(2) * e(1) * e(0),
        }
    }

    /// A one-line description, e.g. `XYZ intrinsic, degrees, axes RUB, pose-para matrices`.
    pub fn describe(&self) -> String {
        format!(
            "{} {}, {}, axes {}, {} matrices",
            self.order.written(self.kind),
            self.kind.name(),
            self.units.name(),
            self.axes,
            self.matrices.name()
        )
    }
}

/// An angle in radians brought into (-π, π].
fn wrap_pi(a: f64) -> f64 {
    let pi = std::f64::consts::PI;
    let r = (a + pi).rem_euclid(2.0 * pi) - pi;
    if r <= -pi { r + 2.0 * pi } else { r }
}

/// Below this, the middle angle's cosine (Tait-Bryan) or sine (proper) is taken as zero.
const LOCK: f64 = 1e-9;

/// The parity of (i, j, k): +1 for a cyclic permutation of (x, y, z), -1 otherwise.
fn parity(i: usize, j: usize, k: usize) -> f64 {
    if (i, j, k) == (0, 1, 2) || (i, j, k) == (1, 2, 0) || (i, j, k) == (2, 0, 1) {
        1.0
    } else {
        -1.0
    }
}

/// Radians `(a, b, c)` with `m = E_i(a) E_j(b) E_k(c)` (standard matrices); at gimbal lock
/// `c = 0`.
fn intrinsic_angles(m: &Matrix3<f64>, order: Order) -> [f64; 3] {
    let [i, j, third] = order.0.map(Axis::index);
    if order.is_tait_bryan() {
        let k = third;
        let e = parity(i, j, k);
        let b = (e * m[(i, k)]).clamp(-1.0, 1.0).asin();
        let cb = m[(i, i)].hypot(m[(i, j)]);
        if cb > LOCK {
            let a = (-e * m[(j, k)]).atan2(m[(k, k)]);
            let c = (-e * m[(i, j)]).atan2(m[(i, i)]);
            [a, b, c]
        } else {
            // m = E_i(a) E_j(±90°): E_i(a) acts on the plane (j, k).
            let a = (e * m[(k, j)]).atan2(m[(j, j)]);
            [a, b, 0.0]
        }
    } else {
        let k = 3 - i - j;
        let e = parity(i, j, k);
        let sb = m[(i, j)].hypot(m[(i, k)]);
        let b = sb.atan2(m[(i, i)]);
        if sb > LOCK {
            let a = m[(j, i)].atan2(-e * m[(k, i)]);
            let c = m[(i, j)].atan2(e * m[(i, k)]);
            [a, b, c]
        } else {
            // m = E_i(a) E_j(0 or 180°).
            let a = (e * m[(k, j)]).atan2(m[(j, j)]);
            [a, b, 0.0]
        }
    }
}

/// As [`intrinsic_angles`], but at gimbal lock the *first* angle is 0 (for an extrinsic order
/// read backwards, whose first applied turn is the intrinsic reading's last).
fn intrinsic_angles_lock_first(m: &Matrix3<f64>, order: Order) -> [f64; 3] {
    let [a, b, c] = intrinsic_angles(m, order);
    let locked = if order.is_tait_bryan() {
        let [i, j, _] = order.0.map(Axis::index);
        m[(i, i)].hypot(m[(i, j)]) <= LOCK
    } else {
        let [i, j, _] = order.0.map(Axis::index);
        let k = 3 - i - j;
        m[(i, j)].hypot(m[(i, k)]) <= LOCK
    };
    if !locked {
        return [a, b, c];
    }
    // m = E_i(a) E_j(b) with c = 0; the same as E_j(b) E_k'(c') with a' = 0 requires moving the
    // turn through the middle one: solve m = E_j(b) · rest for rest = E_j(b)ᵀ m, a turn about
    // the third axis.
    let third = order.0[2];
    let rest = standard_rotation(order.0[1], b).transpose() * m;
    let (p, q) = match third {
        Axis::X => (rest[(2, 1)], rest[(1, 1)]),
        Axis::Y => (rest[(0, 2)], rest[(2, 2)]),
        Axis::Z => (rest[(1, 0)], rest[(0, 0)]),
    };
    [0.0, b, p.atan2(q)]
}
