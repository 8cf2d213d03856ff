//! The landmark list reader (`facepose_records::parse_landmarks`): never panics, and what
//! it accepts serde_json reads as the same points (it is stricter only in refusing lists of
//! more than a scheme's points).
#![no_main]

use facepose_records::parse_landmarks;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let ours = parse_landmarks(text);
    let serde: Result<Vec<Option<[f64; 2]>>, _> = serde_json::from_str(text);
    match (ours, serde) {
        (Ok(ours), Ok(serde)) => {
            assert_eq!(ours.0.len(), serde.len());
            for (a, b) in ours.0.iter().zip(&serde) {
                let bits = |p: &Option<[f64; 2]>| p.map(|[x, y]| (x.to_bits(), y.to_bits()));
                assert_eq!(bits(a), bits(b), "{text:?}");
            }
        }
        (Ok(_), Err(e)) => panic!("accepted what serde_json refuses ({e}): {text:?}"),
        _ => {}
    }
});
