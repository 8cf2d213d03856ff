//! Version ids and the active pointer `DIR/<name>/ACTIVE`: what a valid id is, which id a new
//! version gets, how the pointer's text is read, and how it is replaced atomically.
//!
//! The pointer is one line: a version id and a newline. It is replaced by writing a hidden
//! temporary file beside it, fsyncing it, renaming it over `ACTIVE` and fsyncing the folder, so
//! that a crash at any moment leaves the old pointer or the new one, never a torn or empty one.

use std::fs::{self, File};
use std::io::Write;
use std::path::Path;

use super::file_ops::{VersionError, io, sync_dir, unique_suffix};

/// The active pointer's file name.
pub const ACTIVE_FILE: &str = "ACTIVE";

/// The longest version id.
pub const MAX_ID_LEN: usize = 64;

/// A version id as written by this service: a positive integer without leading zeros.
pub fn numeric(v: &str) -> Option<u64> {
    (!v.starts_with('0'))
        .then(|| v.parse::<u64>().ok())
        .flatten()
        .filter(|&n| n > 0)
}

/// Whether `v` can name a version in a pointer or a request: 1-64 of `A-Z a-z 0-9 . _ + -`,
/// not starting with `.` (numbered versions are `1`, `2`, ...; a legacy bundle's id is its
/// `version` field, which may be any such token).
pub fn valid_id(v: &str) -> bool {
    !v.is_empty()
        && v.len() <= MAX_ID_LEN
        && !v.starts_with('.')
        && v.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"._+-".contains(&b))
}

/// The id of the next version: one more than the highest numeric id among `used` (numbered
/// versions, tombstones of deleted ones, the legacy bundle's id and reserved ids); `1` when none
/// is numeric.
pub fn next_id<'a>(used: impl IntoIterator<Item = &'a str>) -> String {
    let highest = used.into_iter().filter_map(numeric).max().unwrap_or(0);
    (highest + 1).to_string()
}

/// The version an `ACTIVE` file's text names: one valid id, surrounding whitespace (the
/// newline) ignored.
pub fn parse_pointer(text: &str) -> Result<String, String> {
    let v = text.trim();
    if v.is_empty() {
        return Err("is empty: it must name a version".into());
    }
    if !valid_id(v) {
        let shown: String = v.chars().take(80).collect();
        return Err(format!(
            "does not name a version ({shown:?}): it must hold one id such as 3 and a newline"
        ));
    }
    Ok(v.to_string())
}

/// The version `dir/ACTIVE` names; `None` if there is no pointer.
pub fn read_pointer(dir: &Path) -> Result<Option<String>, VersionError> {
    let file = dir.join(ACTIVE_FILE);
    match fs::read_to_string(&file) {
        Ok(s) => parse_pointer(&s)
            .map(Some)
            .map_err(|why| VersionError::Invalid(format!("{} {why}", file.display()))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(io(&file)(e)),
    }
}

/// Replaces `dir/ACTIVE` atomically (temporary file, fsync, rename, fsync of the folder).
pub fn write_pointer(dir: &Path, version: &str) -> Result<(), VersionError> {
    if !valid_id(version) {
        return Err(VersionError::Invalid(format!(
            "invalid version id {version:?}"
        )));
    }
    let tmp = dir.join(format!(".{ACTIVE_FILE}.tmp-{}", unique_suffix()));
    let result = (|| {
        let mut f = File::create(&tmp).map_err(io(&tmp))?;
        f.write_all(format!("{version}\n").as_bytes())
            .map_err(io(&tmp))?;
        f.sync_all().map_err(io(&tmp))?;
        let dst = dir.join(ACTIVE_FILE);
        fs::rename(&tmp, &dst).map_err(io(&dst))?;
        sync_dir(dir)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pointers_name_one_valid_id() {
        assert_eq!(parse_pointer("3\n").unwrap(), "3");
        assert_eq!(parse_pointer("  12 \r\n").unwrap(), "12");
        assert_eq!(parse_pointer("2026.1-rc+b").unwrap(), "2026.1-rc+b");
        for bad in [
            "", "\n", "  ", "3 4", "../1", ".hidden", "a/b", "v\u{e9}", "1\n2\n",
        ] {
            let e = parse_pointer(bad).unwrap_err();
            assert!(
                e.contains("empty") || e.contains("does not name"),
                "{bad:?}: {e}"
            );
        }
        let long = "9".repeat(MAX_ID_LEN + 1);
        assert!(parse_pointer(&long).is_err());
        assert!(parse_pointer(&long[1..]).is_ok());
    }

    #[test]
    fn new_ids_follow_the_highest_number() {
        assert_eq!(next_id([]), "1");
        assert_eq!(next_id(["1", "2", "3"]), "4");
        assert_eq!(next_id(["7", "2"]), "8");
        // Non-numeric and zero-padded ids do not count: they are not ours.
        assert_eq!(next_id(["2026.1", "007", "0", "x9"]), "1");
        assert_eq!(next_id(["2026.1", "5"]), "6");
        assert_eq!(numeric("10"), Some(10));
        assert_eq!(numeric("010"), None);
        assert_eq!(numeric("-1"), None);
        assert_eq!(numeric("1e3"), None);
        assert!(valid_id("1") && valid_id("v1.2_3") && !valid_id("1/2") && !valid_id(""));
    }

    #[test]
    fn a_written_pointer_reads_back() {
        let dir = std::env::temp_dir().join(format!("facepose-pointer-{}", unique_suffix()));
        fs::create_dir_all(&dir).unwrap();
        assert_eq!(read_pointer(&dir).unwrap(), None);
        write_pointer(&dir, "4").unwrap();
        assert_eq!(fs::read_to_string(dir.join(ACTIVE_FILE)).unwrap(), "4\n");
        write_pointer(&dir, "5").unwrap();
        assert_eq!(read_pointer(&dir).unwrap().as_deref(), Some("5"));
        assert!(write_pointer(&dir, "../x").is_err());
        // No temporary file is left behind.
        let left: Vec<_> = fs::read_dir(&dir).unwrap().flatten().collect();
        assert_eq!(left.len(), 1, "{left:?}");
        fs::write(dir.join(ACTIVE_FILE), "").unwrap();
        let e = read_pointer(&dir).unwrap_err().to_string();
        assert!(
            e.ends_with("ACTIVE is empty: it must name a version"),
            "{e}"
        );
        fs::remove_dir_all(&dir).unwrap();
    }
}
