//! Records the commit compend is built from, for `compend --version`: `COMPEND_COMMIT` is the
//! short hash of `git rev-parse HEAD`, or `unknown` outside a git checkout (a source tarball)
//! or without git. Uncommitted changes are not told apart.

use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    let text = String::from_utf8_lossy(&out.stdout).trim().to_string();
    (out.status.success() && !text.is_empty()).then_some(text)
}

fn main() {
    let commit = git(&["rev-parse", "--short=12", "HEAD"]).unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=COMPEND_COMMIT={commit}");
    // A new commit moves the branch HEAD names (or HEAD itself, detached); a change of branch
    // moves HEAD.
    let mut watched = vec![".git/HEAD".to_string(), ".git/packed-refs".to_string()];
    if let Ok(head) = std::fs::read_to_string(".git/HEAD")
        && let Some(name) = head.trim().strip_prefix("ref: ")
    {
        watched.push(format!(".git/{name}"));
    }
    for path in watched {
        if std::path::Path::new(&path).exists() {
            println!("cargo:rerun-if-changed={path}");
        }
    }
}
