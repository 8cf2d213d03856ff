//! The model bundle loader (a file in the shared models folder, written by any replica):
//! parsing and loading never panic, whatever the text.
#![no_main]

use facepose_core::model::bundle::Bundle;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(bundle) = Bundle::parse(text) {
        let _ = bundle.compute_checksum();
        let _ = bundle.load();
    }
});
