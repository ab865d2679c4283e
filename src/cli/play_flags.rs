//! What `compend play` checks of its flags before anything plays, shared by one projector's
//! playback (`play`) and a set's (`play_set`): the folder `--out` writes the camera's views
//! into, and `--rig`'s spelling.

use std::path::Path;

use compend::rig;

/// The list `play --out` keeps in its folder. The camera views' names are not known before the
/// playback ends, so it names what `play` writes there rather than each file.
const PLAY_MARKER: &str = ".compend-played";

/// Whether `dir` may take `play`'s files (`play.json`, `cam_NNNNNN.png`): a folder (or nothing
/// yet) that holds none of them, or one an earlier `play` wrote them into (its marker is
/// there). Input errors name the path. [`mark_out`] marks it before the first is written.
pub fn check_out(dir: &Path) -> compend::Result<()> {
    super::check_out_folder(dir, "--out")?;
    let marker = dir.join(PLAY_MARKER);
    if !marker.exists() {
        let ours = |name: &str| {
            name == "play.json" || (name.starts_with("cam_") && name.ends_with(".png"))
        };
        if let Ok(entries) = std::fs::read_dir(dir)
            && let Some(name) = entries
                .filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .find(|n| ours(n))
        {
            return Err(compend::Error::Input(format!(
                "{}: already there, and not written by `compend play` (no {PLAY_MARKER} \
                 beside it), so it is not replaced: choose another --out",
                dir.join(name).display()
            )));
        }
    }
    Ok(())
}

/// Makes `dir` and marks it as `play`'s ([`check_out`]).
pub fn mark_out(dir: &Path) -> compend::Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| compend::Error::io(dir, "create folder", e))?;
    compend::files::write_atomically(
        &dir.join(PLAY_MARKER),
        b"# play.json and cam_NNNNNN.png here are written by `compend play`\n",
    )
}

/// `virtual` → None, `virtual:SCENE` → Some(SCENE).
pub fn parse_rig(s: &str) -> compend::Result<Option<String>> {
    match s.split_once(':') {
        None if s == "virtual" => Ok(None),
        Some(("virtual", scene)) if !scene.is_empty() => Ok(Some(scene.to_string())),
        _ => Err(compend::Error::Input(format!(
            "--rig {s:?}: expected `virtual` or `virtual:SCENE` (scenes: {})",
            rig::BUILTIN.join(", ")
        ))),
    }
}
