//! Model versions in the models folder (`--models DIR`), and the rules that keep the folder
//! consistent when the process is killed at any moment and when several replicas share it.
//!
//! ```text
//! DIR/<name>/model.json                 legacy bundle: a version named by its `version` field
//! DIR/<name>/versions/<N>/model.json    version N (1, 2, ...), each written atomically
//! DIR/<name>/ACTIVE                     the active version's id and a newline
//! DIR/<name>/.lock                      locked (flock) while an id is chosen, a version written,
//!                                       the pointer replaced or a version deleted
//! DIR/<name>/versions/.<N>.deleted      tombstone: id N was used and is never given again
//! hidden entries ".*tmp-*", ".*.deleting-*": writes or deletions in progress or interrupted
//! ```
//!
//! Invariants (each write is ordered so that a crash between any two steps keeps them):
//! - A version directory is complete and checksummed once it has its name: it is written under
//!   a hidden temporary name, fsynced and renamed (`store::write_bundle_dir`).
//! - `ACTIVE` names a complete version: the pointer is replaced only after the version's rename
//!   is durable and after this process has loaded the version, atomically
//!   ([`super::pointer::write_pointer`]). A crash leaves the old pointer or the new one, never a
//!   torn one.
//! - A version is immutable: nothing here writes into a version folder once it has its name;
//!   the bundle's checksum, verified at every load, tells if something else did.
//! - Without `ACTIVE`, the active version is the legacy bundle (or, for `default`, the embedded
//!   model); a version written but never activated stays inactive.
//! - Ids are chosen and written under the model's lock: two replicas never write the same id;
//!   tombstones keep deleted ids from coming back.
//! - Hidden entries are ignored when loading and removed only when older than [`STALE_AGE`],
//!   so never while another replica may still be writing them.
//!
//! Plain blocking file I/O: callers run it off the async reactor.

use std::fs::{self, File, OpenOptions};
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::pointer::{next_id, numeric, read_pointer, write_pointer};
use facepose_core::model::bundle::Bundle;
use facepose_files::store::{MODEL_FILE, write_bundle_dir};

/// The folder of numbered versions.
pub const VERSIONS_DIR: &str = "versions";
const LOCK_FILE: &str = ".lock";
/// Hidden temporary entries older than this are removed (a write takes well under a second).
pub const STALE_AGE: Duration = Duration::from_secs(10 * 60);

pub use super::file_ops::VersionError;
use super::file_ops::{io, sync_dir, unique_suffix};

/// One version on disk.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StoredVersion {
    /// The version's id.
    pub version: String,
    /// Its bundle file.
    pub file: PathBuf,
    /// The legacy `DIR/<name>/model.json`.
    pub legacy: bool,
}

/// One model's folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StoredModel {
    /// The folder's name.
    pub name: String,
    /// The folder's path.
    pub dir: PathBuf,
    /// Versions in numeric order, the legacy bundle among them (first if its id is not a
    /// number).
    pub versions: Vec<StoredVersion>,
    /// The content of `ACTIVE`, if any.
    pub pointer: Option<String>,
    /// The legacy bundle's version, read from the file (only when there is one).
    pub legacy_version: Option<String>,
}

impl StoredModel {
    /// The version named `version`.
    pub fn get(&self, version: &str) -> Option<&StoredVersion> {
        // A numbered version wins over a legacy bundle with the same id.
        self.versions
            .iter()
            .find(|v| v.version == version && !v.legacy)
            .or_else(|| self.versions.iter().find(|v| v.version == version))
    }

    /// The active version's id: the pointer's, else the legacy bundle's.
    pub fn active(&self) -> Option<&str> {
        self.pointer.as_deref().or(self.legacy_version.as_deref())
    }

    /// Every version's id, in order.
    pub fn ids(&self) -> Vec<String> {
        self.versions.iter().map(|v| v.version.clone()).collect()
    }
}

/// A model name usable as a folder name: 1-64 of `a-z 0-9 _ . -`, starting with a letter or
/// digit (`jobs` is reserved for the API's job routes).
pub fn check_name(name: &str) -> Result<(), VersionError> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b"_.-".contains(&b))
        && name.as_bytes()[0].is_ascii_alphanumeric()
        && name != "jobs";
    if ok {
        Ok(())
    } else {
        Err(VersionError::Invalid(format!(
            "invalid model name {name:?}: use 1-64 characters a-z, 0-9, '_', '.', '-', starting \
             with a letter or digit (not \"jobs\")"
        )))
    }
}

/// Every model folder of `root` (hidden ones skipped), by name. Entries that are not model
/// folders (see [`model_entries`]) and folders that cannot be read (e.g. a root-owned
/// `lost+found` on a volume) are skipped, with a warning when `warn` is set; other problems
/// (a pointer that names no valid id, a legacy bundle without a version) fail.
pub fn scan(root: &Path, warn: bool) -> Result<Vec<StoredModel>, VersionError> {
    let (names, skipped) = model_entries(root)?;
    if warn {
        for n in &skipped {
            tracing::warn!(entry = %root.join(n).display(),
                "not a model folder (not a valid model name, no model.json): ignored");
        }
    }
    let mut out = Vec::new();
    for n in names {
        match scan_model(root, &n) {
            Ok(m) => out.extend(m),
            Err(e @ VersionError::Io { .. }) => {
                if warn {
                    tracing::warn!(entry = %root.join(&n).display(), error = %e,
                        "cannot read this entry of the models folder: ignored");
                } else {
                    tracing::debug!(entry = %root.join(&n).display(), error = %e,
                        "cannot read this entry of the models folder: ignored");
                }
            }
            Err(e) => return Err(e),
        }
    }
    Ok(out)
}

/// The entries of `root` that may be model folders, sorted, and those skipped: hidden
/// entries and files are not listed at all; folders whose name is not a valid model name
/// ([`check_name`]) and that hold no `model.json` are skipped (`lost+found`, ...).
pub fn model_entries(root: &Path) -> Result<(Vec<String>, Vec<String>), VersionError> {
    let mut names = Vec::new();
    let mut skipped = Vec::new();
    for entry in fs::read_dir(root).map_err(io(root))? {
        let entry = entry.map_err(io(root))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') || !entry.path().is_dir() {
            continue;
        }
        if check_name(&name).is_err() && !entry.path().join(MODEL_FILE).is_file() {
            skipped.push(name);
        } else {
            names.push(name);
        }
    }
    names.sort();
    skipped.sort();
    Ok((names, skipped))
}

/// Every model folder of `root` (as [`model_entries`] lists them), by name, each with its own
/// outcome: one unreadable folder does not hide the others.
#[allow(clippy::type_complexity)]
pub fn scan_each(
    root: &Path,
) -> Result<Vec<(String, Result<Option<StoredModel>, VersionError>)>, VersionError> {
    let (names, _) = model_entries(root)?;
    Ok(names
        .into_iter()
        .map(|n| {
            let m = scan_model(root, &n);
            (n, m)
        })
        .collect())
}

/// The model folder `root/name`, or `None` when it has neither a legacy bundle, nor versions,
/// nor a pointer.
pub fn scan_model(root: &Path, name: &str) -> Result<Option<StoredModel>, VersionError> {
    let dir = root.join(name);
    if !dir.is_dir() {
        return Ok(None);
    }
    let mut versions = Vec::new();
    let vdir = dir.join(VERSIONS_DIR);
    if vdir.is_dir() {
        for entry in fs::read_dir(&vdir).map_err(io(&vdir))? {
            let entry = entry.map_err(io(&vdir))?;
            let id = entry.file_name().to_string_lossy().into_owned();
            let file = entry.path().join(MODEL_FILE);
            if numeric(&id).is_some() && file.is_file() {
                versions.push(StoredVersion {
                    version: id,
                    file,
                    legacy: false,
                });
            }
        }
    }
    versions.sort_by_key(|v| numeric(&v.version));
    let legacy = dir.join(MODEL_FILE);
    let legacy_version = if legacy.is_file() {
        let v = read_version_field(&legacy)?;
        let at = versions
            .iter()
            .position(|s| numeric(&s.version) > numeric(&v))
            .unwrap_or(versions.len());
        versions.insert(
            at,
            StoredVersion {
                version: v.clone(),
                file: legacy,
                legacy: true,
            },
        );
        Some(v)
    } else {
        None
    };
    let pointer = read_pointer(&dir)?;
    if versions.is_empty() && pointer.is_none() {
        return Ok(None);
    }
    Ok(Some(StoredModel {
        name: name.into(),
        dir,
        versions,
        pointer,
        legacy_version,
    }))
}

/// The `version` field of a bundle file, without validating the rest.
fn read_version_field(file: &Path) -> Result<String, VersionError> {
    #[derive(serde::Deserialize)]
    struct Head {
        version: String,
    }
    let text = fs::read_to_string(file).map_err(io(file))?;
    serde_json::from_str::<Head>(&text)
        .map(|h| h.version)
        .map_err(|e| {
            VersionError::Invalid(format!(
                "{}: no readable version field: {e}",
                file.display()
            ))
        })
}

/// The model's lock, held until dropped. The folder is created if needed.
struct Lock(File);

impl Lock {
    fn take(dir: &Path) -> Result<Lock, VersionError> {
        create_durable(dir)?;
        let path = dir.join(LOCK_FILE);
        let f = OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .map_err(io(&path))?;
        f.lock().map_err(io(&path))?;
        Ok(Lock(f))
    }
}

impl Drop for Lock {
    fn drop(&mut self) {
        let _ = self.0.unlock();
    }
}

/// Writes a new version of model `name` under `root` and returns its id and bundle file. The
/// id is one more than the highest used so far (numbered versions, tombstones, the legacy
/// bundle's id and `reserved`, e.g. the embedded default's version); `make` builds the bundle
/// for that id. The version is not activated.
pub fn write_version(
    root: &Path,
    name: &str,
    reserved: &[&str],
    make: impl FnOnce(&str) -> Result<Bundle, VersionError>,
) -> Result<(String, PathBuf), VersionError> {
    check_name(name)?;
    let dir = root.join(name);
    let _lock = Lock::take(&dir)?;
    let vdir = dir.join(VERSIONS_DIR);
    create_durable(&vdir)?;
    let mut used: Vec<String> = reserved.iter().map(|v| v.to_string()).collect();
    if let Some(m) = scan_model(root, name)? {
        used.extend(m.ids());
    }
    for entry in fs::read_dir(&vdir).map_err(io(&vdir))? {
        let entry = entry.map_err(io(&vdir))?;
        let f = entry.file_name().to_string_lossy().into_owned();
        if let Some(id) = f.strip_prefix('.').and_then(|s| s.strip_suffix(".deleted")) {
            used.push(id.to_string());
        } else if numeric(&f).is_some() {
            // Every numbered entry counts, also one without a bundle (copied in by hand,
            // damaged): its name is taken.
            used.push(f);
        }
    }
    let version = next_id(used.iter().map(String::as_str));
    let bundle = make(&version)?;
    let target = vdir.join(&version);
    write_bundle_dir(&target, &bundle)?;
    Ok((version, target.join(MODEL_FILE)))
}

/// Creates `dir` (and its missing parents) so that the new entries survive a power loss: each
/// created folder's parent is fsynced.
fn create_durable(dir: &Path) -> Result<(), VersionError> {
    if dir.is_dir() {
        return Ok(());
    }
    if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        create_durable(parent)?;
    }
    match fs::create_dir(dir) {
        Ok(()) => {}
        // Another replica made it meanwhile.
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => return Ok(()),
        Err(e) => return Err(io(dir)(e)),
    }
    match dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        Some(parent) => sync_dir(parent),
        None => Ok(()),
    }
}

/// Makes `version` the active version of `name`, under the model's lock; `exists` says whether
/// a version that is not on disk is still valid (the embedded default). The caller has loaded
/// the version already: the pointer only ever names a version that loads.
pub fn activate(
    root: &Path,
    name: &str,
    version: &str,
    exists_elsewhere: bool,
) -> Result<(), VersionError> {
    check_name(name)?;
    let dir = root.join(name);
    let _lock = Lock::take(&dir)?;
    let model = scan_model(root, name)?;
    let on_disk = model.as_ref().is_some_and(|m| m.get(version).is_some());
    if !(on_disk || exists_elsewhere) {
        return Err(VersionError::NotFound {
            name: name.into(),
            version: version.into(),
            existing: model.map(|m| m.ids()).unwrap_or_default(),
        });
    }
    write_pointer(&dir, version)
}

/// Deletes an inactive numbered version of `name` (tombstone first, then the folder is renamed
/// to a hidden name and removed).
pub fn delete_version(root: &Path, name: &str, version: &str) -> Result<(), VersionError> {
    check_name(name)?;
    let not_found = |existing| VersionError::NotFound {
        name: name.into(),
        version: version.into(),
        existing,
    };
    let dir = root.join(name);
    if !dir.is_dir() {
        return Err(not_found(vec![]));
    }
    let _lock = Lock::take(&dir)?;
    let Some(model) = scan_model(root, name)? else {
        return Err(not_found(vec![]));
    };
    let Some(v) = model.get(version) else {
        return Err(not_found(model.ids()));
    };
    if model.active() == Some(version) {
        return Err(VersionError::Active {
            name: name.into(),
            version: version.into(),
        });
    }
    if v.legacy {
        return Err(VersionError::Legacy {
            name: name.into(),
            version: version.into(),
            path: v.file.clone(),
        });
    }
    let vdir = dir.join(VERSIONS_DIR);
    let tomb = vdir.join(format!(".{version}.deleted"));
    File::create(&tomb).map_err(io(&tomb))?;
    let src = vdir.join(version);
    let gone = vdir.join(format!(".{version}.deleting-{}", unique_suffix()));
    fs::rename(&src, &gone).map_err(io(&src))?;
    sync_dir(&vdir)?;
    fs::remove_dir_all(&gone).map_err(io(&gone))
}

/// Deletes the inactive numbered versions of `name` beyond the `keep` newest (by id), as
/// [`delete_version`] does: the active version, the legacy bundle and the `keep` newest others
/// stay. A version activated or deleted meanwhile (by another replica) is left to it. Returns
/// the ids deleted.
pub fn prune(root: &Path, name: &str, keep: usize) -> Result<Vec<String>, VersionError> {
    let Some(model) = scan_model(root, name)? else {
        return Ok(vec![]);
    };
    let active = model.active();
    let mut inactive: Vec<(u64, &str)> = model
        .versions
        .iter()
        .filter(|v| !v.legacy && Some(v.version.as_str()) != active)
        .filter_map(|v| Some((numeric(&v.version)?, v.version.as_str())))
        .collect();
    inactive.sort_unstable_by(|a, b| b.cmp(a));
    let mut deleted = Vec::new();
    for &(_, version) in inactive.iter().skip(keep) {
        match delete_version(root, name, version) {
            Ok(()) => deleted.push(version.to_string()),
            Err(VersionError::Active { .. } | VersionError::NotFound { .. }) => {}
            Err(e) => return Err(e),
        }
    }
    Ok(deleted)
}

/// Removes hidden temporary entries of a model folder (and its versions folder) older than
/// `age`: interrupted writes and deletions. Returns what was removed.
pub fn clean_stale(model_dir: &Path, age: Duration) -> Vec<PathBuf> {
    let mut removed = Vec::new();
    for dir in [model_dir.to_path_buf(), model_dir.join(VERSIONS_DIR)] {
        let Ok(entries) = fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            let temporary =
                name.starts_with('.') && (name.contains(".tmp-") || name.contains(".deleting-"));
            if !temporary {
                continue;
            }
            let old = entry
                .metadata()
                .and_then(|m| m.modified())
                .ok()
                .and_then(|t| t.elapsed().ok())
                .is_some_and(|e| e >= age);
            if !old {
                continue;
            }
            let path = entry.path();
            let ok = if path.is_dir() {
                fs::remove_dir_all(&path).is_ok()
            } else {
                fs::remove_file(&path).is_ok()
            };
            if ok {
                removed.push(path);
            }
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_root(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("facepose-versions-{tag}-{}", unique_suffix()));
        fs::create_dir_all(&d).unwrap();
        d
    }

    fn bundle(name: &str, version: &str) -> Bundle {
        let mut b = Bundle::parse(facepose_core::model::DEFAULT_BUNDLE).unwrap();
        b.name = name.into();
        b.version = version.into();
        b.checksum = b.compute_checksum().unwrap();
        b
    }

    fn add(root: &Path, name: &str) -> String {
        write_version(root, name, &[], |v| Ok(bundle(name, v)))
            .unwrap()
            .0
    }

    #[test]
    fn ids_grow_and_are_never_reused() {
        let root = temp_root("ids");
        assert_eq!(add(&root, "m"), "1");
        assert_eq!(add(&root, "m"), "2");
        assert_eq!(add(&root, "m"), "3");
        activate(&root, "m", "1", false).unwrap();
        delete_version(&root, "m", "3").unwrap();
        assert_eq!(add(&root, "m"), "4");
        // Reserved ids (the embedded default's) and the legacy bundle's count too.
        let legacy = root.join("d");
        fs::create_dir_all(&legacy).unwrap();
        fs::write(legacy.join(MODEL_FILE), bundle("d", "7").to_json()).unwrap();
        assert_eq!(add(&root, "d"), "8");
        assert_eq!(
            write_version(&root, "e", &["5"], |v| Ok(bundle("e", v)))
                .unwrap()
                .0,
            "6"
        );
        let m = scan_model(&root, "m").unwrap().unwrap();
        assert_eq!(m.ids(), ["1", "2", "4"]);
        assert_eq!(m.active(), Some("1"));
        let d = scan_model(&root, "d").unwrap().unwrap();
        assert_eq!(d.ids(), ["7", "8"]);
        assert!(d.get("7").unwrap().legacy);
        assert_eq!(
            d.active(),
            Some("7"),
            "without a pointer the legacy bundle is active"
        );
        fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn activation_and_deletion_rules() {
        let root = temp_root("rules");
        let legacy = root.join("m");
        fs::create_dir_all(&legacy).unwrap();
        fs::write(legacy.join(MODEL_FILE), bundle("m", "1").to_json()).unwrap();
        assert_eq!(add(&root, "m"), "2");
        assert!(matches!(
            activate(&root, "m", "9", false),
            Err(VersionError::NotFound { .. })
        ));
        activate(&root, "m", "2", false).unwrap();
        assert_eq!(read_pointer(&legacy).unwrap().as_deref(), Some("2"));
        let e = delete_version(&root, "m", "2").unwrap_err();
        assert!(matches!(e, VersionError::Active { .. }), "{e}");
        let e = delete_version(&root, "m", "1").unwrap_err();
        assert!(matches!(e, VersionError::Legacy { .. }), "{e}");
        let e = delete_version(&root, "m", "5").unwrap_err();
        assert_eq!(
            e.to_string(),
            "model \"m\" has no version \"5\"; it has 1, 2"
        );
        assert!(matches!(
            delete_version(&root, "nope", "1"),
            Err(VersionError::NotFound { .. })
        ));
        // Names that are not folder names.
        for bad in ["", "../x", "A", "jobs", ".hidden", "a/b"] {
            assert!(check_name(bad).is_err(), "{bad:?}");
        }
        // An embedded version can be activated without a file.
        activate(&root, "m", "0-embedded", true).unwrap();
        fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn pruning_keeps_the_active_the_legacy_and_the_newest_inactive() {
        let root = temp_root("prune");
        let ids: Vec<String> = (0..6).map(|_| add(&root, "m")).collect();
        assert_eq!(ids, ["1", "2", "3", "4", "5", "6"]);
        activate(&root, "m", "2", false).unwrap();
        // Inactive: 6 5 4 3 1; the two newest stay.
        assert_eq!(prune(&root, "m", 2).unwrap(), ["4", "3", "1"]);
        let m = scan_model(&root, "m").unwrap().unwrap();
        assert_eq!(m.ids(), ["2", "5", "6"]);
        assert_eq!(m.active(), Some("2"));
        assert!(prune(&root, "m", 2).unwrap().is_empty());
        // Deleted ids are never given again.
        assert_eq!(add(&root, "m"), "7");
        assert_eq!(prune(&root, "m", 0).unwrap(), ["7", "6", "5"]);
        assert_eq!(scan_model(&root, "m").unwrap().unwrap().ids(), ["2"]);
        assert!(prune(&root, "absent", 0).unwrap().is_empty());
        let _ = fs::remove_dir_all(&root);
    }

    #[test]
    fn every_crash_point_leaves_a_complete_active_version() {
        // The folder as a crash would leave it after each step of a write and an activation.
        let root = temp_root("crash");
        assert_eq!(add(&root, "m"), "1");
        activate(&root, "m", "1", false).unwrap();
        let dir = root.join("m");
        let vdir = dir.join(VERSIONS_DIR);
        // 1. Killed while writing version 2: a hidden temporary folder with a torn file.
        fs::create_dir_all(vdir.join(".2.tmp-1-1")).unwrap();
        fs::write(vdir.join(".2.tmp-1-1").join(MODEL_FILE), "{ half").unwrap();
        // 2. Killed while replacing the pointer: a hidden temporary pointer.
        fs::write(dir.join(".ACTIVE.tmp-1-2"), "2").unwrap();
        // 3. Killed while deleting: a hidden folder being removed.
        fs::create_dir_all(vdir.join(".3.deleting-1-3")).unwrap();
        let m = scan_model(&root, "m").unwrap().unwrap();
        assert_eq!(m.ids(), ["1"]);
        assert_eq!(m.active(), Some("1"));
        facepose_files::store::load_model(&m.get("1").unwrap().file).unwrap();
        // Fresh temporaries stay (another replica may be writing them); old ones go.
        assert!(clean_stale(&dir, STALE_AGE).is_empty());
        assert_eq!(clean_stale(&dir, Duration::ZERO).len(), 3);
        assert!(!vdir.join(".2.tmp-1-1").exists());
        // The next write after the crash takes id 2 (the torn one never had it).
        assert_eq!(add(&root, "m"), "2");
        fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn entries_that_are_not_model_folders_do_not_stop_a_scan() {
        use std::os::unix::fs::PermissionsExt;
        let root = temp_root("foreign");
        assert_eq!(add(&root, "m"), "1");
        // A volume's lost+found, unreadable by the service's user (when it is not root).
        let lf = root.join("lost+found");
        fs::create_dir_all(lf.join("#1234")).unwrap();
        fs::set_permissions(&lf, fs::Permissions::from_mode(0o000)).unwrap();
        // A folder with an invalid name whose pointer would not parse.
        let bad = root.join("Not A Model");
        fs::create_dir_all(&bad).unwrap();
        fs::write(bad.join("ACTIVE"), "garbage garbage").unwrap();
        let (names, skipped) = model_entries(&root).unwrap();
        assert_eq!(names, ["m"]);
        assert_eq!(skipped, ["Not A Model", "lost+found"]);
        let all = scan(&root, true).unwrap();
        assert_eq!(
            all.iter().map(|m| m.name.as_str()).collect::<Vec<_>>(),
            ["m"]
        );
        assert_eq!(scan_each(&root).unwrap().len(), 1);
        // The models load.
        let set = crate::registry::load_models(Some(&root)).unwrap();
        assert!(set.get(None).is_ok());
        // A valid name that cannot be read is skipped too (only without root's rights).
        let locked = root.join("locked");
        fs::create_dir_all(locked.join(VERSIONS_DIR)).unwrap();
        fs::set_permissions(&locked, fs::Permissions::from_mode(0o000)).unwrap();
        let readable = fs::read_dir(&locked).is_ok();
        let all = scan(&root, true).unwrap();
        if !readable {
            assert_eq!(all.len(), 1);
        }
        for d in [&lf, &locked] {
            fs::set_permissions(d, fs::Permissions::from_mode(0o755)).unwrap();
        }
        fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn a_numbered_entry_without_a_bundle_takes_its_id() {
        let root = temp_root("nobundle");
        assert_eq!(add(&root, "m"), "1");
        let vdir = root.join("m").join(VERSIONS_DIR);
        fs::create_dir_all(vdir.join("2")).unwrap();
        fs::write(vdir.join("5"), "not a folder").unwrap();
        assert_eq!(add(&root, "m"), "6");
        assert_eq!(scan_model(&root, "m").unwrap().unwrap().ids(), ["1", "6"]);
        fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn two_writers_never_share_an_id() {
        let root = temp_root("race");
        let ids: Vec<String> = std::thread::scope(|s| {
            let hs: Vec<_> = (0..4).map(|_| s.spawn(|| add(&root, "m"))).collect();
            hs.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let mut sorted = ids.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(sorted.len(), 4, "{ids:?}");
        fs::remove_dir_all(&root).unwrap();
    }
}
