//! Files written whole or not at all: what lets a run killed at any instant be read and
//! resumed.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

/// Writes `path` whole or not at all: into `<name>.partial` beside it, synced to the disk, then
/// renamed over `path`. A run killed at any instant leaves the old file or the new one, never a
/// part of one (a frame, particles.pvd, run.toml, the checkpoint); a failed write leaves the old
/// file and no `.partial`.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    let tmp = path.with_file_name(name);
    let mut w = BufWriter::new(File::create(&tmp)?);
    let written = write(&mut w)
        .and_then(|_| w.flush())
        .and_then(|_| w.get_ref().sync_all());
    if let Err(e) = written {
        drop(w);
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    drop(w);
    std::fs::rename(&tmp, path)
}
