//! The angle convention against AFLW2000-3D's own `Pose_Para` rotations.

use crate::common;

use facepose_core::geometry::{EulerAngles, rotation_from_rows};
use facepose_files::data::load_aflw;

#[test]
fn every_rotation_of_the_dev_split_matches_its_angles() {
    let faces = load_aflw(&common::data_file("aflw2000/aflw2000_dev.jsonl")).unwrap();
    assert_eq!(faces.len(), 500);
    for f in &faces {
        let ours = EulerAngles::new(f.yaw, f.pitch, f.roll)
            .unwrap()
            .to_rotation();
        let theirs = f.rotation;
        for (i, row) in theirs.iter().enumerate() {
            for (j, &value) in row.iter().enumerate() {
                let d = (ours.matrix()[(i, j)] - value).abs();
                assert!(d < 1e-6, "{}: R[{i}][{j}] differs by {d}", f.image);
            }
        }
        // And back: the dataset's matrix gives its angles where they are canonical (yaw within
        // ±89°, pitch and roll within ±180°); otherwise the same rotation.
        let back = EulerAngles::from_rotation(&rotation_from_rows(theirs, 1e-5).unwrap());
        let err = (back.to_rotation().matrix() - ours.matrix()).abs().max();
        assert!(err < 1e-6, "{}: matrix round trip {err}", f.image);
        if f.yaw.abs() < 89.0 && f.pitch.abs() < 180.0 && f.roll.abs() < 180.0 {
            assert!((back.yaw - f.yaw).abs() < 1e-4, "{}", f.image);
            assert!((back.pitch - f.pitch).abs() < 1e-4, "{}", f.image);
            assert!((back.roll - f.roll).abs() < 1e-4, "{}", f.image);
        }
    }
}
