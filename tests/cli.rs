//! The command line's front door: the help lists what a user needs first, and the shell
//! completions and manual pages are made from the command line itself.

use crate::common::{assert_code, compend, stderr, stdout};

#[test]
fn help_completions_and_manual_pages_come_from_the_command_line() {
    // The user's commands before the tools, the benchmarks last, and only in a build with the
    // `benches` feature.
    let help = stdout(&compend(&["--help"]));
    let at = |name: &str| {
        help.find(&format!("\n  {name} "))
            .unwrap_or_else(|| panic!("{name} not listed in:\n{help}"))
    };
    assert!(
        at("calibrate") < at("serve") && at("serve") < at("train"),
        "{help}"
    );
    if cfg!(feature = "benches") {
        assert!(
            at("train") < at("bench") && at("sim") < at("bench-gpu"),
            "{help}"
        );
    } else {
        assert!(!help.contains("\n  bench"), "{help}");
    }
    let v = stdout(&compend(&["--version"]));
    assert_eq!(
        v.contains("benches"),
        cfg!(feature = "benches"),
        "the version names the benches feature when built with it: {v}"
    );

    // The version says which commit and which features.
    let v = stdout(&compend(&["--version"]));
    assert!(
        v.starts_with(&format!("compend {} (commit ", env!("CARGO_PKG_VERSION"))),
        "{v}"
    );
    assert!(v.contains("; features: "), "{v}");

    let bash = compend(&["completions", "bash"]);
    assert_code(&bash, 0);
    for word in ["_compend()", "calibrate", "--ntrain", "--loop-images"] {
        assert!(stdout(&bash).contains(word), "{word} in\n{}", stdout(&bash));
    }
    let zsh = compend(&["completions", "zsh"]);
    assert_code(&zsh, 0);
    assert!(
        stdout(&zsh).starts_with("#compdef compend"),
        "{}",
        stdout(&zsh)
    );
    let o = compend(&["completions", "tcsh"]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("bash"), "{}", stderr(&o));

    let page = compend(&["man"]);
    assert_code(&page, 0);
    let text = stdout(&page);
    assert!(text.contains(".TH compend 1"), "{text}");
    assert!(
        text.contains("calibrate") && text.contains("serve"),
        "{text}"
    );
    let page = compend(&["man", "calibrate"]);
    assert_code(&page, 0);
    let text = stdout(&page);
    assert!(text.contains(".TH compend-calibrate 1"), "{text}");
    assert!(text.contains(env!("CARGO_PKG_VERSION")), "{text}");
    assert!(text.contains("\\-\\-ntrain"), "{text}");
    let o = compend(&["man", "calibrat"]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("man calibrat: no such command; the commands are calibrate,"),
        "{}",
        stderr(&o)
    );
    // Every page into a folder, as the package's build writes them; not into a file.
    let dir = tempfile::tempdir().unwrap();
    let pages = dir.path().to_str().unwrap();
    assert_code(&compend(&["man", "--dir", pages]), 0);
    for page in ["compend.1", "compend-calibrate.1", "compend-config-check.1"] {
        let text = std::fs::read_to_string(dir.path().join(page))
            .unwrap_or_else(|e| panic!("{page} in {pages}: {e}"));
        assert!(text.contains(env!("CARGO_PKG_VERSION")), "{page}: {text}");
    }
    let file = dir.path().join("compend.1");
    let o = compend(&["man", "--dir", file.to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("not a folder"), "{}", stderr(&o));

    // The page is one groff reads without a warning, where groff is installed.
    let groff = std::process::Command::new("groff")
        .args(["-man", "-Tutf8", "-ww", "-z"])
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn();
    if let Ok(mut child) = groff {
        use std::io::Write;
        child
            .stdin
            .take()
            .unwrap()
            .write_all(text.as_bytes())
            .unwrap();
        let out = child.wait_with_output().unwrap();
        assert!(out.status.success(), "groff failed");
        assert_eq!(String::from_utf8_lossy(&out.stderr), "", "groff warned");
    }
}
