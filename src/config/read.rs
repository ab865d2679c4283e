//! The reader of a configuration file: the document parsed with spans, each section taken out of
//! it and walked key by key ([`Walker`]); each section's own file says which keys it takes and
//! their defaults.

use std::ops::Range;
use std::path::Path;
use std::str::FromStr;

use serde::de::DeserializeOwned;
use toml::Spanned;
use toml::de::{DeTable, DeValue, ValueDeserializer};

use super::Config;
use crate::error::Error;
use crate::raster::ImageSize;

/// The largest value a number of seconds, hertz or milliseconds may take (about 31 years in
/// seconds): beyond it, durations overflow.
const LARGEST: f64 = 1e9;

/// A table being read: what is left of it, its name and where it is.
pub(super) struct Table<'i> {
    pub(super) name: &'static str,
    pub(super) entries: Vec<(String, Range<usize>, Spanned<DeValue<'i>>)>,
}

/// The reader: collects errors and the keys it asked for.
pub(super) struct Walker<'t> {
    text: &'t str,
    file: String,
    pub(super) errors: Vec<(usize, String)>,
    pub(super) asked: Vec<String>,
}

impl<'t> Walker<'t> {
    pub(super) fn new(text: &'t str, path: &Path) -> Self {
        Self {
            text,
            file: path.display().to_string(),
            errors: Vec::new(),
            asked: Vec::new(),
        }
    }

    pub(super) fn line(&self, offset: usize) -> usize {
        let end = offset.min(self.text.len());
        self.text.as_bytes()[..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
            + 1
    }

    pub(super) fn error(&mut self, span: Range<usize>, message: String) {
        let line = self.line(span.start);
        self.errors.push((line, message));
    }

    pub(super) fn into_error(mut self) -> Error {
        self.errors.sort_by_key(|(line, _)| *line);
        let n = self.errors.len();
        let lines: Vec<String> = self
            .errors
            .iter()
            .map(|(line, m)| format!("  {}:{line}: {m}", self.file))
            .collect();
        Error::Input(format!(
            "{}: {n} error{} in the configuration:\n{}",
            self.file,
            if n == 1 { "" } else { "s" },
            lines.join("\n")
        ))
    }

    /// Reads the whole document; `None` when it is not TOML at all.
    pub(super) fn document(&mut self) -> Option<Config> {
        let (root, parse_errors) = DeTable::parse_recoverable(self.text);
        for e in &parse_errors {
            let span = e.span().unwrap_or(0..0);
            // What the span covers (a key given twice, a bad value), when it is short.
            let at = self
                .text
                .get(span.clone())
                .and_then(|s| s.lines().next())
                .map(str::trim)
                .filter(|s| !s.is_empty() && s.chars().count() <= 80)
                .map_or(String::new(), |s| format!(" (at `{s}`)"));
            self.error(span, format!("not valid TOML: {}{at}", e.message().trim()));
        }
        if !parse_errors.is_empty() {
            return None;
        }
        let mut root = Table {
            name: "",
            entries: entries(root.into_inner()),
        };
        let config = super::sections(self, &mut root);
        self.finish(root);
        Some(config)
    }

    /// `allow`: networks (`10.0.0.0/24`) or single addresses.
    pub(super) fn networks(&mut self, t: &mut Table<'t>) -> Vec<ipnet::IpNet> {
        let span = span_of(t, "allow");
        let allow: Vec<String> = self.get(t, "allow").unwrap_or_default();
        let mut nets = Vec::new();
        for a in &allow {
            match a
                .parse::<ipnet::IpNet>()
                .or_else(|_| a.parse::<std::net::IpAddr>().map(ipnet::IpNet::from))
            {
                Ok(n) => nets.push(n),
                Err(_) => self.error(
                    span.clone(),
                    format!(
                        "[{}] allow: \"{a}\" is not a network; expected an address or \
                         ADDRESS/BITS such as \"10.0.0.0/24\"",
                        t.name
                    ),
                ),
            }
        }
        nets
    }

    /// Takes section `name` out of `root`; a missing one is empty.
    pub(super) fn table(&mut self, root: &mut Table<'t>, name: &'static str) -> Table<'t> {
        let empty = Table {
            name,
            entries: Vec::new(),
        };
        let Some(i) = root.entries.iter().position(|(k, _, _)| k == name) else {
            return empty;
        };
        let (_, span, value) = root.entries.remove(i);
        match value.into_inner() {
            DeValue::Table(t) => Table {
                name,
                entries: entries(t),
            },
            other => {
                self.error(
                    span,
                    format!(
                        "`{name}` must be a section ([{name}]), not {}",
                        with_article(other.type_str())
                    ),
                );
                empty
            }
        }
    }

    /// Takes the array of sections `name` (`[[name]]`) out of `root`, each with where it is;
    /// none when it is missing.
    pub(super) fn tables(
        &mut self,
        root: &mut Table<'t>,
        name: &'static str,
    ) -> Vec<(Range<usize>, Table<'t>)> {
        let Some(i) = root.entries.iter().position(|(k, _, _)| k == name) else {
            return Vec::new();
        };
        let (_, span, value) = root.entries.remove(i);
        let wrong = |w: &mut Self, what: &str| {
            w.error(
                span.clone(),
                format!("`{name}` must be sections ([[{name}]]), not {what}"),
            )
        };
        match value.into_inner() {
            DeValue::Array(items) => {
                let mut out = Vec::new();
                for item in items {
                    let at = item.span();
                    match item.into_inner() {
                        DeValue::Table(t) => out.push((
                            at,
                            Table {
                                name,
                                entries: entries(t),
                            },
                        )),
                        other => wrong(self, &with_article(other.type_str())),
                    }
                }
                out
            }
            other => {
                wrong(self, &with_article(other.type_str()));
                Vec::new()
            }
        }
    }

    /// Takes `key` out of `t` and deserialises it; `None` when absent or wrong (recorded).
    pub(super) fn get<T: DeserializeOwned>(&mut self, t: &mut Table<'t>, key: &str) -> Option<T> {
        self.asked.push(format!("{}.{key}", t.name));
        let i = t.entries.iter().position(|(k, _, _)| k == key)?;
        let (_, _, value) = t.entries.remove(i);
        let span = value.span();
        let type_name = with_article(value.get_ref().type_str());
        match T::deserialize(ValueDeserializer::from(value)) {
            Ok(v) => Some(v),
            Err(e) => {
                let what = std::any::type_name::<T>();
                self.error(
                    span,
                    format!(
                        "[{}] {key}: {} (expected {}, got {type_name})",
                        t.name,
                        e.message().trim(),
                        expected_name(what)
                    ),
                );
                None
            }
        }
    }

    /// `key` with `check`, else `default` (a failed check is recorded).
    pub(super) fn checked<T: DeserializeOwned>(
        &mut self,
        t: &mut Table<'t>,
        key: &str,
        default: T,
        check: impl FnOnce(&T) -> std::result::Result<(), String>,
    ) -> T {
        let span = span_of(t, key);
        match self.get::<T>(t, key) {
            None => default,
            Some(v) => match check(&v) {
                Ok(()) => v,
                Err(m) => {
                    self.error(span, format!("[{}] {key}: {m}", t.name));
                    default
                }
            },
        }
    }

    /// A string parsed by `parse`; `None` when absent or wrong (recorded).
    pub(super) fn parsed_with<T>(
        &mut self,
        t: &mut Table<'t>,
        key: &str,
        parse: impl FnOnce(&str) -> std::result::Result<T, String>,
    ) -> Option<T> {
        let span = span_of(t, key);
        let s: String = self.get(t, key)?;
        match parse(&s) {
            Ok(v) => Some(v),
            Err(m) => {
                self.error(span, format!("[{}] {key}: {m}", t.name));
                None
            }
        }
    }

    pub(super) fn parsed<T: FromStr>(&mut self, t: &mut Table<'t>, key: &str, default: T) -> T
    where
        T::Err: std::fmt::Display,
    {
        self.parsed_with(t, key, |s| T::from_str(s).map_err(|e| e.to_string()))
            .unwrap_or(default)
    }

    pub(super) fn choice<T: Copy>(
        &mut self,
        t: &mut Table<'t>,
        key: &str,
        default: T,
        options: &[(&str, T)],
    ) -> T {
        self.parsed_with(t, key, |s| {
            options
                .iter()
                .find(|(name, _)| *name == s)
                .map(|(_, v)| *v)
                .ok_or_else(|| {
                    let names: Vec<String> =
                        options.iter().map(|(n, _)| format!("\"{n}\"")).collect();
                    format!("\"{s}\" is not one of {}", names.join(", "))
                })
        })
        .unwrap_or(default)
    }

    pub(super) fn size(
        &mut self,
        t: &mut Table<'t>,
        key: &str,
        square_ok: bool,
    ) -> Option<ImageSize> {
        self.parsed_with(t, key, |s| ImageSize::parse(s, square_ok))
    }

    pub(super) fn positive(&mut self, t: &mut Table<'t>, key: &str, default: f64) -> f64 {
        self.optional_positive(t, key).unwrap_or(default)
    }

    pub(super) fn optional_positive(&mut self, t: &mut Table<'t>, key: &str) -> Option<f64> {
        let span = span_of(t, key);
        let v: f64 = self.get(t, key)?;
        if v.is_finite() && v > 0.0 && v <= LARGEST {
            Some(v)
        } else {
            self.error(
                span,
                format!(
                    "[{}] {key}: {v} must be a positive number, at most {LARGEST:e}",
                    t.name
                ),
            );
            None
        }
    }

    pub(super) fn optional_non_negative(&mut self, t: &mut Table<'t>, key: &str) -> Option<f64> {
        let span = span_of(t, key);
        let v: f64 = self.get(t, key)?;
        if v.is_finite() && (0.0..=LARGEST).contains(&v) {
            Some(v)
        } else {
            self.error(
                span,
                format!(
                    "[{}] {key}: {v} must be zero or more, at most {LARGEST:e}",
                    t.name
                ),
            );
            None
        }
    }

    /// Whatever is left in `t` is unknown.
    pub(super) fn finish(&mut self, t: Table<'t>) {
        let prefix = if t.name.is_empty() {
            String::new()
        } else {
            format!("{}.", t.name)
        };
        let known: Vec<String> = self
            .asked
            .iter()
            .filter_map(|k| k.strip_prefix(&prefix))
            .filter(|k| !k.contains('.') || prefix.is_empty())
            .map(str::to_string)
            .collect();
        for (key, span, _) in t.entries {
            let place = if t.name.is_empty() {
                "top level".to_string()
            } else {
                format!("[{}]", t.name)
            };
            let known_here: Vec<&str> = if t.name.is_empty() {
                SECTIONS.to_vec()
            } else {
                known.iter().map(String::as_str).collect()
            };
            let hint = nearest(&key, &known_here)
                .map(|k| format!("; did you mean `{k}`?"))
                .unwrap_or_else(|| format!("; known: {}", known_here.join(", ")));
            self.error(span, format!("unknown key `{key}` at the {place}{hint}"));
        }
    }
}

/// The sections, in the order of the shipped file.
pub(super) const SECTIONS: [&str; 12] = [
    "rig",
    "projector",
    "paths",
    "calibration",
    "playback",
    "audio",
    "output",
    "monitoring",
    "socket",
    "http",
    "osc",
    "log",
];

pub(super) fn entries(t: DeTable<'_>) -> Vec<(String, Range<usize>, Spanned<DeValue<'_>>)> {
    t.into_iter()
        .map(|(k, v)| {
            let span = k.span();
            (k.into_inner().into_owned(), span, v)
        })
        .collect()
}

pub(super) fn span_of(t: &Table<'_>, key: &str) -> Range<usize> {
    t.entries
        .iter()
        .find(|(k, _, _)| k == key)
        .map_or(0..0, |(_, _, v)| v.span())
}

pub(super) fn at_least_one(n: usize) -> std::result::Result<(), String> {
    if n >= 1 {
        Ok(())
    } else {
        Err("must be at least 1".into())
    }
}

pub(super) fn finite(v: f64) -> std::result::Result<(), String> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(format!("{v} is not a number of dB"))
    }
}

/// What a Rust type is called in a TOML file.
fn expected_name(type_name: &str) -> &'static str {
    match type_name {
        t if t.contains("SamplingCount") => "a whole number or \"auto\"",
        t if t.contains("PathBuf") => "a path string",
        t if t.contains("String") => "a string",
        "bool" => "true or false",
        "f64" | "f32" => "a number",
        "u64" | "u32" | "usize" => "a whole number",
        t if t.contains("Vec<u32>") => "a list of whole numbers",
        _ => "another type",
    }
}

/// The known key closest to `key` by edit distance (insertions, deletions, substitutions and
/// swaps of two neighbouring characters: a typed `sede` is one edit from `seed`, two from
/// `scene`), when it is close.
fn nearest<'a>(key: &str, known: &[&'a str]) -> Option<&'a str> {
    known
        .iter()
        .map(|k| (strsim::osa_distance(key, k), *k))
        .filter(|(d, k)| *d <= 2.max(k.len() / 3))
        .min_by_key(|(d, _)| *d)
        .map(|(_, k)| k)
}

/// A TOML type's name with its article: "an integer", "a string".
fn with_article(name: &str) -> String {
    let article = if name.starts_with(['a', 'e', 'i', 'o', 'u']) {
        "an"
    } else {
        "a"
    };
    format!("{article} {name}")
}
