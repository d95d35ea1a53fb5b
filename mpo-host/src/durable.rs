//! Files that survive a crash: written through a temporary, fsynced, renamed into place, the
//! directory fsynced after. The checkpoint, the metrics and `config.toml` are written so.

use std::fs;
use std::io::Write;
use std::path::Path;

/// fsync of a directory, so the entries created, renamed or removed in it are durable.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    fs::File::open(dir)?.sync_all()
}

/// Writes `bytes` to a new file at `path` and fsyncs it (not its directory).
pub fn write_synced(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut f = fs::File::create(path)?;
    f.write_all(bytes)?;
    f.sync_all()
}

/// Writes a file through a temporary and a rename, so a reader (or a crash) never sees half:
/// the temporary is fsynced before the rename and the directory after it, so once this
/// returns the new contents survive a crash or power loss. On an error (a full disk, say) the
/// temporary is removed and `path` keeps its previous contents.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = path.with_extension("tmp");
    if let Err(e) = write_synced(&tmp, bytes) {
        let _ = fs::remove_file(&tmp);
        return Err(e);
    }
    fs::rename(&tmp, path)?;
    sync_dir(path.parent().unwrap_or(Path::new(".")))
}
