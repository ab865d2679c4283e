//! Writing files so that nothing is lost (docs/architecture.md, "Errors and files"): the one
//! atomic-write helper every writer uses, the naming of temporary siblings, the cleaning of
//! what killed runs left behind, and the directory swap that replaces a model.
//!
//! - A file is written to a temporary sibling `.NAME.tmp-PID`, fsynced, renamed over `NAME`,
//!   and the folder is fsynced: a reader (or a crash) sees the old file or the new one, never a
//!   half-written one.
//! - A directory (a model) is written complete under `.NAME.tmp-PID` and then exchanged with
//!   the old one in one step (`renameat2(RENAME_EXCHANGE)` on Linux), so the final path always
//!   holds a complete directory; the old one is removed after the exchange.
//! - Temporary siblings of processes that no longer run are removed by the next write of the
//!   same name ([`clean_stale_siblings`]); those of a live process are left alone.

use std::fs;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Marker between a name and the writer's PID in a temporary sibling: `.NAME.tmp-PID`.
const TMP_MARK: &str = ".tmp-";
/// Marker of a previous directory moved aside by the fallback swap: `.NAME.old-PID`.
const OLD_MARK: &str = ".old-";

/// The bytes of `path`, which must be a regular file (symbolic links followed) of at most
/// `max_bytes`, described as `what` ("a PNG image", say) in the errors. A FIFO, a device, a
/// socket or a folder is refused before it is opened ([`open_regular`]): an input error naming
/// it, with no wait for a writer. A missing file is [`Error::Missing`]; a file larger than
/// `max_bytes` (`/dev/zero` would be endless) is an input error before it is read.
pub fn read_regular(path: &Path, what: &str, max_bytes: u64) -> Result<Vec<u8>> {
    let (file, len) = open_regular(path, what)?;
    read_opened(file, len, (path, what), max_bytes)
}

/// The rest of `file`, opened from `path` by [`open_regular`] with its length `len`, as
/// [`read_regular`] reads it: at most `max_bytes`, an input error past them.
pub fn read_opened(
    file: fs::File,
    len: u64,
    (path, what): (&Path, &str),
    max_bytes: u64,
) -> Result<Vec<u8>> {
    use std::io::Read;
    let too_big = |len: u64| {
        Error::Input(format!(
            "{}: {len} bytes or more; {what} may hold at most {max_bytes} bytes",
            path.display()
        ))
    };
    if len > max_bytes {
        return Err(too_big(len));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    // A file that grows while it is read stops at the cap.
    file.take(max_bytes + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, "read", e))?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

/// `path` opened for reading, with its length in bytes, when it is a regular file (symbolic
/// links followed); the errors as for [`read_regular`].
pub fn open_regular(path: &Path, what: &str) -> Result<(fs::File, u64)> {
    use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
    let not = |kind: fs::FileType| {
        let is = if kind.is_dir() {
            "a folder"
        } else if kind.is_fifo() {
            "a FIFO (named pipe)"
        } else if kind.is_char_device() || kind.is_block_device() {
            "a device"
        } else if kind.is_socket() {
            "a socket"
        } else {
            "not a regular file"
        };
        Error::Input(format!("{}: {is}, not {what}", path.display()))
    };
    let missing = |e: std::io::Error| match e.kind() {
        std::io::ErrorKind::NotFound => Error::Missing {
            path: path.to_path_buf(),
            expected: what.to_string(),
        },
        _ => Error::io(path, "open", e),
    };
    // Looked at before it is opened (opening a device can act: a terminal, a watchdog), and
    // again once open, in case it was swapped in between; non-blocking and without taking a
    // terminal, so that the open itself never waits or acts.
    let kind = fs::metadata(path).map_err(missing)?.file_type();
    if !kind.is_file() {
        return Err(not(kind));
    }
    let file = fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)
        .map_err(missing)?;
    let meta = file.metadata().map_err(|e| Error::io(path, "inspect", e))?;
    if !meta.file_type().is_file() {
        return Err(not(meta.file_type()));
    }
    Ok((file, meta.len()))
}

/// The most bytes a weights file compend reads may hold (a model's, a pre-initialisation's;
/// the full-size residual rung's are tens of megabytes).
pub const MAX_WEIGHTS_BYTES: u64 = 4 << 30;

/// The most bytes an image file compend reads may hold: a 16-bit RGBA PNG of the largest size
/// compend takes ([`crate::raster::ImageSize::MAX_PIXELS`]), stored uncompressed, with room.
pub const MAX_IMAGE_BYTES: u64 = 1 << 30;

/// The most bytes a text file compend reads (a configuration, a model's or a scene's JSON, a
/// capture manifest) may hold.
pub const MAX_TEXT_BYTES: u64 = 64 << 20;

/// The text of `path`, a regular file of at most [`MAX_TEXT_BYTES`] ([`read_regular`]) holding
/// UTF-8; `what` names it in the errors.
pub fn read_text(path: &Path, what: &str) -> Result<String> {
    String::from_utf8(read_regular(path, what, MAX_TEXT_BYTES)?).map_err(|e| {
        Error::Input(format!(
            "{}: not text (invalid UTF-8 at byte {}); expected {what}",
            path.display(),
            e.utf8_error().valid_up_to()
        ))
    })
}

/// The folder holding `path` (`.` for a bare name).
pub fn parent_of(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// The last component of `path` as a string; an input error for `/`, `..` and the like.
pub fn file_name_of(path: &Path) -> Result<String> {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| {
            Error::Input(format!(
                "{}: not a usable file or folder name",
                path.display()
            ))
        })
}

/// This process's temporary sibling of `path`: `.NAME.tmp-PID` in the same folder (the same
/// file system, so the final rename is atomic).
pub fn temp_sibling(path: &Path) -> Result<PathBuf> {
    let name = file_name_of(path)?;
    Ok(parent_of(path).join(format!(".{name}{TMP_MARK}{}", std::process::id())))
}

/// Moves the complete file `tmp` (a temporary sibling) to `path`, never over a file there: the
/// file is synced, linked under the new name (which fails when it is taken) and the temporary
/// name removed, then the folder synced. A name taken meanwhile is an input error naming it,
/// with `tmp` left for the user.
pub fn rename_no_replace(tmp: &Path, path: &Path) -> Result<()> {
    if let Ok(f) = fs::File::open(tmp) {
        f.sync_all().map_err(|e| Error::io(tmp, "sync", e))?;
    }
    match fs::hard_link(tmp, path) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
            return Err(Error::Input(format!(
                "{}: a file appeared there while it was written; the output is kept as {}",
                path.display(),
                tmp.display()
            )));
        }
        Err(e) => return Err(Error::io(path, "move into place", e)),
    }
    fs::remove_file(tmp).map_err(|e| Error::io(tmp, "remove", e))?;
    sync_dir(parent_of(path));
    Ok(())
}

/// Writes `bytes` to `path` atomically (temporary sibling, fsync, rename, fsync of the folder).
/// The folder is created when missing.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_with(path, |w| {
        w.write_all(bytes).map_err(|e| Error::io(path, "write", e))
    })
}

/// Like [`write_atomically`], with the content produced by `fill` into a buffered writer (an
/// encoder streams into it). On any error the temporary file is removed and `path` untouched.
pub fn write_with(path: &Path, fill: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    let parent = parent_of(path);
    fs::create_dir_all(parent).map_err(|e| Error::io(parent, "create folder", e))?;
    let tmp = temp_sibling(path)?;
    clean_stale_siblings(path);
    let result = (|| {
        let file = fs::File::create(&tmp).map_err(|e| Error::io(&tmp, "create", e))?;
        let mut out = BufWriter::new(file);
        fill(&mut out)?;
        let file = out
            .into_inner()
            .map_err(|e| Error::io(&tmp, "write", e.into_error()))?;
        file.sync_all().map_err(|e| Error::io(&tmp, "sync", e))?;
        drop(file);
        fs::rename(&tmp, path).map_err(|e| Error::io(path, "move into place", e))
    })();
    match result {
        Ok(()) => {
            sync_dir(parent);
            Ok(())
        }
        Err(e) => {
            let _ = fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// Creates (or empties) this process's temporary sibling folder of `dir`, for a directory that
/// [`swap_in_dir`] will put in place.
pub fn temp_dir_for(dir: &Path) -> Result<PathBuf> {
    let parent = parent_of(dir);
    fs::create_dir_all(parent).map_err(|e| Error::io(parent, "create folder", e))?;
    clean_stale_siblings(dir);
    let tmp = temp_sibling(dir)?;
    if tmp.exists() {
        fs::remove_dir_all(&tmp)
            .map_err(|e| Error::io(&tmp, "remove stale temporary folder", e))?;
    }
    fs::create_dir(&tmp).map_err(|e| Error::io(&tmp, "create", e))?;
    Ok(tmp)
}

/// Writes one file of a folder being built: fsynced, no rename (the folder is swapped whole).
pub fn write_synced(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut f = fs::File::create(path).map_err(|e| Error::io(path, "create", e))?;
    f.write_all(bytes)
        .map_err(|e| Error::io(path, "write", e))?;
    f.sync_all().map_err(|e| Error::io(path, "sync", e))
}

/// Puts the complete folder `tmp` (a sibling of `dir`, from [`temp_dir_for`]) at `dir`. When
/// `dir` exists, the two are exchanged in one step and the old one is then removed: at every
/// moment `dir` holds either the old or the new folder. Once the new folder is in place the
/// swap has succeeded: an old folder that cannot be removed is a warning naming where it was
/// left. The caller has checked that what is at `dir` may be replaced. Where the file system
/// cannot exchange, the old folder is moved aside, the new one renamed in, and the old one put
/// back if that fails (a moment with no folder).
pub fn swap_in_dir(tmp: &Path, dir: &Path) -> Result<()> {
    let parent = parent_of(dir);
    sync_dir(tmp);
    if !dir.exists() {
        fs::rename(tmp, dir).map_err(|e| Error::io(dir, "move the new folder into place", e))?;
        sync_dir(parent);
        return Ok(());
    }
    match exchange(tmp, dir) {
        Ok(()) => {
            sync_dir(parent);
            // `tmp` now holds the previous folder.
            remove_previous(tmp, dir);
            Ok(())
        }
        Err(e) if exchange_unsupported(&e) => swap_by_renames(tmp, dir),
        Err(e) => Err(Error::io(dir, "exchange with the new folder", e)),
    }
}

fn swap_by_renames(tmp: &Path, dir: &Path) -> Result<()> {
    let parent = parent_of(dir);
    let name = file_name_of(dir)?;
    let old = parent.join(format!(".{name}{OLD_MARK}{}", std::process::id()));
    fs::rename(dir, &old).map_err(|e| Error::io(dir, "move the previous folder aside", e))?;
    if let Err(e) = fs::rename(tmp, dir) {
        let _ = fs::rename(&old, dir); // put the previous folder back
        return Err(Error::io(dir, "move the new folder into place", e));
    }
    sync_dir(parent);
    remove_previous(&old, dir);
    Ok(())
}

/// Removes the previous folder of `dir`, moved to `old` by a swap; a failure is a warning (the
/// new folder is already in place).
fn remove_previous(old: &Path, dir: &Path) {
    if let Err(e) = fs::remove_dir_all(old) {
        tracing::warn!(
            "{}: the new folder is in place, but the previous one could not be removed from {} \
             ({e}); remove it once that is mended (a later run writing {} removes it if it can)",
            dir.display(),
            old.display(),
            dir.display()
        );
    }
}

#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use nix::fcntl::{AT_FDCWD, RenameFlags, renameat2};
    renameat2(AT_FDCWD, a, AT_FDCWD, b, RenameFlags::RENAME_EXCHANGE).map_err(std::io::Error::from)
}

#[cfg(not(target_os = "linux"))]
fn exchange(_: &Path, _: &Path) -> std::io::Result<()> {
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// The file system or kernel cannot exchange two paths atomically.
fn exchange_unsupported(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::Unsupported
        || matches!(
            e.raw_os_error().map(nix::errno::Errno::from_raw),
            Some(nix::errno::Errno::EINVAL | nix::errno::Errno::ENOSYS)
        )
}

/// Removes the temporary siblings of `path` (`.NAME.tmp-PID`, `.NAME.old-PID`) left by
/// processes that no longer run: a write killed half-way. Best effort: what cannot be listed or
/// removed stays, and nothing else is touched.
pub fn clean_stale_siblings(path: &Path) {
    let Ok(name) = file_name_of(path) else { return };
    let Ok(entries) = fs::read_dir(parent_of(path)) else {
        return;
    };
    let prefix = format!(".{name}");
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some(rest) = file_name.to_str().and_then(|n| n.strip_prefix(&prefix)) else {
            continue;
        };
        let Some(pid) = [TMP_MARK, OLD_MARK]
            .iter()
            .find_map(|m| rest.strip_prefix(m))
            .and_then(|pid| pid.parse::<u32>().ok())
        else {
            continue;
        };
        if pid == std::process::id() || process_alive(pid) {
            continue;
        }
        let stale = entry.path();
        let _ = match entry.file_type() {
            Ok(t) if t.is_dir() => fs::remove_dir_all(&stale),
            _ => fs::remove_file(&stale),
        };
    }
}

/// Whether a process with this PID runs (signal 0 reaches it, or it exists but is not ours).
fn process_alive(pid: u32) -> bool {
    let Ok(pid) = i32::try_from(pid) else {
        return false;
    };
    // Signal 0 only checks whether the process exists.
    match nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid), None) {
        Ok(()) | Err(nix::errno::Errno::EPERM) => true,
        Err(_) => false,
    }
}

/// fsyncs a folder so a rename inside it survives a power cut. Best effort: a folder that
/// cannot be opened (some file systems) is skipped.
pub fn sync_dir(dir: &Path) {
    if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Whether this process may create and remove entries in the folder `dir` (write and search
/// permission, a file system mounted writable), as `access(2)` answers for the effective IDs.
fn may_write_in(dir: &Path) -> std::io::Result<()> {
    use nix::unistd::AccessFlags;
    nix::unistd::faccessat(
        nix::fcntl::AT_FDCWD,
        dir,
        AccessFlags::W_OK | AccessFlags::X_OK,
        nix::fcntl::AtFlags::AT_EACCESS,
    )
    .map_err(std::io::Error::from)
}

/// Checks, before any work, that what the existing folder `dir` holds can be removed (the
/// folder is writable and searchable by this process), as replacing it will: an input error
/// (exit 2) naming it otherwise.
pub fn check_contents_removable(dir: &Path) -> Result<()> {
    may_write_in(dir).map_err(|e| {
        Error::Input(format!(
            "{}: what it holds cannot be removed to replace it ({e}); make the folder writable \
             or choose another --out",
            dir.display()
        ))
    })
}

/// Checks, before any work, that results can be written into the folder `dir` (a benchmark's
/// `--out`): it is a folder, or can be made one, and a file can be created in it or in the
/// nearest of its folders that exists ([`check_writable`]). Errors as that one's.
pub fn check_out_folder(dir: &Path) -> Result<()> {
    match fs::metadata(dir) {
        Ok(m) if m.is_dir() => check_writable(&dir.join("results")),
        Ok(_) => Err(Error::Input(format!(
            "{}: is a file, not a folder for the results",
            dir.display()
        ))),
        // A link to nothing cannot be made a folder.
        Err(e) if e.kind() == std::io::ErrorKind::NotFound && fs::symlink_metadata(dir).is_ok() => {
            Err(Error::Input(format!(
                "{}: a link to nothing, not a folder for the results",
                dir.display()
            )))
        }
        // Made when the results are written: its nearest existing folder must take it.
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => check_writable(dir),
        Err(e) => Err(Error::Input(format!(
            "{}: cannot be used as the folder for the results ({e})",
            dir.display()
        ))),
    }
}

/// Checks, before any work, that `path` can be written: a file can be created in the nearest
/// of its folders that exists (the missing ones are created when `path` is written, not now,
/// so a run that fails leaves none behind). An input error (exit 2) naming the path when it
/// cannot be (a file on the way, a name too long); an I/O error (exit 1) when this user may
/// not write there, the file system is read-only or the disk or quota is full.
pub fn check_writable(path: &Path) -> Result<()> {
    // `child`: the entry of `folder` on the way to `path` (`path` itself when its folder
    // exists), whose temporary sibling is the probe.
    let (mut child, mut folder) = (path, parent_of(path));
    loop {
        match fs::metadata(folder) {
            Ok(m) if m.is_dir() => break,
            Ok(_) => {
                return Err(Error::Input(format!(
                    "{}: {} is a file, not a folder",
                    path.display(),
                    folder.display()
                )));
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound && parent_of(folder) != folder => {
                (child, folder) = (folder, parent_of(folder));
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotADirectory => {
                return Err(Error::Input(format!(
                    "{}: a folder on this path is a file",
                    path.display()
                )));
            }
            Err(e) => {
                return Err(Error::Input(format!(
                    "{}: cannot reach the output folder {} ({e})",
                    path.display(),
                    folder.display()
                )));
            }
        }
    }
    // Our own temporary name; `create_new` never truncates anything that is there. A real
    // file, not `access(2)`, which can say yes where a write fails (NFS with root squashed).
    let probe = temp_sibling(child)?;
    match fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
    {
        Ok(_) => {
            let _ = fs::remove_file(&probe);
            Ok(())
        }
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        // Not this user's to write, or no room: the operation's failure (exit 1, which a
        // service manager retries once the rights or the room are there), not a wrong path.
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::PermissionDenied
                    | std::io::ErrorKind::ReadOnlyFilesystem
                    | std::io::ErrorKind::StorageFull
                    | std::io::ErrorKind::QuotaExceeded
            ) =>
        {
            Err(Error::Io {
                path: folder.to_path_buf(),
                op: "write a file (to check that the output can go there)",
                source: e,
            })
        }
        Err(e) => Err(Error::Input(format!(
            "{}: cannot write in {} ({e})",
            path.display(),
            folder.display()
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A regular file is read whole; a folder, a FIFO, a device, a missing path and a file
    /// over the cap are errors naming the path, at once (a FIFO with no writer is not waited
    /// on).
    #[test]
    fn only_a_regular_file_within_the_cap_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.png");
        fs::write(&file, b"12345").unwrap();
        assert_eq!(read_regular(&file, "an image", 5).unwrap(), b"12345");
        let fifo = dir.path().join("f.png");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::from_bits_truncate(0o600)).unwrap();
        for (path, says, code) in [
            (
                file.clone(),
                "5 bytes or more; an image may hold at most 4 bytes",
                2,
            ),
            (dir.path().to_path_buf(), "a folder, not an image", 2),
            (fifo, "a FIFO (named pipe), not an image", 2),
            (PathBuf::from("/dev/zero"), "a device, not an image", 2),
            (dir.path().join("none.png"), "none.png", 2),
        ] {
            let e = read_regular(&path, "an image", 4).unwrap_err();
            assert_eq!(e.exit_code(), code, "{e}");
            let e = e.to_string();
            assert!(e.contains(says), "{e}");
            assert!(e.contains(&path.display().to_string()), "{e}");
        }
        let e = read_text(&file.with_extension("bin"), "text").unwrap_err();
        assert_eq!(e.exit_code(), 2);
        fs::write(&file, [0xff, 0xfe]).unwrap();
        let e = read_text(&file, "a TOML file").unwrap_err().to_string();
        assert!(e.contains("not text (invalid UTF-8 at byte 0)"), "{e}");
    }

    #[test]
    fn a_folder_is_exchanged_whole_and_the_old_one_removed() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("model");
        fs::create_dir(&target).unwrap();
        fs::write(target.join("a"), b"old").unwrap();
        let tmp = temp_dir_for(&target).unwrap();
        fs::write(tmp.join("a"), b"new").unwrap();
        swap_in_dir(&tmp, &target).unwrap();
        assert_eq!(fs::read(target.join("a")).unwrap(), b"new");
        assert!(!tmp.exists());
        let names: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1);
    }

    #[test]
    fn a_writable_output_is_checked_without_creating_its_folders() {
        let dir = tempfile::tempdir().unwrap();
        let deep = dir.path().join("a").join("b").join("model");
        check_writable(&deep).unwrap();
        assert!(
            !dir.path().join("a").exists(),
            "nothing is created before the work"
        );
        let file = dir.path().join("f");
        fs::write(&file, b"x").unwrap();
        let e = check_writable(&file.join("model")).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("is a file, not a folder"), "{e}");
        let e = check_writable(&file.join("a").join("model")).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(
            e.to_string().contains("a folder on this path is a file"),
            "{e}"
        );
    }

    #[test]
    fn a_results_folder_is_checked_before_any_work() {
        let dir = tempfile::tempdir().unwrap();
        // A folder, or one to be made (nothing made now), and a folder that holds files.
        let fresh = dir.path().join("a/b");
        check_out_folder(&fresh).unwrap();
        assert!(!dir.path().join("a").exists());
        std::fs::write(dir.path().join("kept"), "x").unwrap();
        check_out_folder(dir.path()).unwrap();
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "the probe is gone");
        // A file, or a link to nothing: input errors naming them.
        let e = check_out_folder(&dir.path().join("kept")).unwrap_err();
        assert!(
            matches!(&e, Error::Input(m) if m.contains("kept: is a file")),
            "{e}"
        );
        let link = dir.path().join("dangling");
        std::os::unix::fs::symlink(dir.path().join("nowhere"), &link).unwrap();
        let e = check_out_folder(&link).unwrap_err();
        assert!(
            matches!(&e, Error::Input(m) if m.contains("a link to nothing")),
            "{e}"
        );
        assert_eq!(
            std::fs::read_to_string(dir.path().join("kept")).unwrap(),
            "x"
        );
    }

    #[test]
    fn stale_siblings_of_dead_processes_go_and_live_ones_stay() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.png");
        // PID 1 always runs; 999999999 is above any PID Linux hands out.
        let live = dir.path().join(".out.png.tmp-1");
        let dead = dir.path().join(".out.png.tmp-999999999");
        let dead_dir = dir.path().join(".out.png.old-999999998");
        let other = dir.path().join(".out.png.notes");
        for f in [&live, &dead, &other] {
            fs::write(f, b"x").unwrap();
        }
        fs::create_dir(&dead_dir).unwrap();
        write_atomically(&target, b"png").unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"png");
        assert!(live.exists() && other.exists());
        assert!(!dead.exists() && !dead_dir.exists());
    }

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("f.json");
        fs::write(&target, b"good").unwrap();
        let err = write_with(&target, |_| Err(Error::Failed("encoder failed".into())));
        assert!(err.is_err());
        assert_eq!(fs::read(&target).unwrap(), b"good");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
