//! `cargo xtask api [--bless]`: the public API of every library crate as text, one line per
//! item, compared with the snapshot under `api/` — so that a change of the API is a decision
//! (the snapshot changes in the same commit), not an accident. A unit test runs the comparison,
//! so the test suite fails on an unrecorded change.
//!
//! The API is read from rustdoc's JSON output (the format cargo-semver-checks and
//! cargo-public-api read; on a stable toolchain it needs `RUSTC_BOOTSTRAP=1` for rustdoc's
//! `-Z unstable-options`, given to rustdoc alone).
//! What a line shows: every public path (re-exports included), struct fields, enum variants,
//! function signatures with their generics, inherent methods, trait items and the traits a type
//! implements. Types are named by their last path segment, and by `crate::Name` when another
//! crate (outside the standard library) defines them.

use std::collections::{BTreeSet, HashSet};
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};
use serde_json::Value;

/// The library crates whose API is recorded, in publication order.
pub const CRATES: [&str; 13] = [
    "timesift-core",
    "timesift-geometry",
    "timesift-film",
    "timesift-io",
    "timesift-synth",
    "timesift-bundle",
    "timesift-features",
    "timesift-matching",
    "timesift-align",
    "timesift-change",
    "timesift-eval",
    "timesift-dense",
    "timesift-raster",
];

/// The workspace root (xtask sits one level below it).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from(".."))
}

/// Where the snapshot of `krate` is kept.
fn snapshot_path(root: &Path, krate: &str) -> PathBuf {
    root.join("api").join(format!("{krate}.txt"))
}

/// Compares every crate's API with its snapshot (or rewrites the snapshots with `bless`);
/// returns the differences found, one block per crate.
pub fn check(root: &Path, bless: bool) -> anyhow::Result<Vec<String>> {
    let docs = rustdoc_json(root)?;
    let mut differences = Vec::new();
    for krate in CRATES {
        let json = read_rustdoc_json(&docs, krate)?;
        let lines = render(&json).with_context(|| format!("reading the API of {krate}"))?;
        let text = format!(
            "# Public API of {krate} (cargo xtask api --bless rewrites this file)\n{}\n",
            lines.join("\n")
        );
        let path = snapshot_path(root, krate);
        if bless {
            std::fs::create_dir_all(path.parent().unwrap_or(root))?;
            std::fs::write(&path, &text).with_context(|| format!("writing {}", path.display()))?;
            continue;
        }
        let recorded = std::fs::read_to_string(&path).unwrap_or_default();
        if recorded != text {
            differences.push(describe_difference(krate, &path, &recorded, &text));
        }
    }
    Ok(differences)
}

/// The lines only one side has.
fn describe_difference(krate: &str, path: &Path, recorded: &str, now: &str) -> String {
    let old: BTreeSet<&str> = recorded.lines().collect();
    let new: BTreeSet<&str> = now.lines().collect();
    let mut out = format!(
        "{krate}: the public API differs from {} (run `cargo xtask api --bless` if the change \
         is meant):\n",
        path.display()
    );
    for line in old.difference(&new) {
        out.push_str(&format!("  - {line}\n"));
    }
    for line in new.difference(&old) {
        out.push_str(&format!("  + {line}\n"));
    }
    out
}

/// Runs rustdoc's JSON backend on every library of the workspace in one `cargo doc` (features
/// unified as in the workspace's own builds, so the check builds of the dependencies are the
/// ones `cargo clippy` or `cargo check` make in the same target folder, and the crates are
/// documented in parallel);
/// returns the folder of the `<crate>.json` files. Only rustdoc is told it may use unstable
/// options (through a wrapper that sets `RUSTC_BOOTSTRAP` for it alone): build scripts that look
/// at that variable would otherwise change how the dependencies are built.
fn rustdoc_json(root: &Path) -> anyhow::Result<PathBuf> {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("target"));
    let wrapper = rustdoc_wrapper(&target)?;
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let output = Command::new(cargo)
        .current_dir(root)
        .env("RUSTDOC", &wrapper)
        .env("RUSTDOCFLAGS", "-Z unstable-options --output-format json")
        .env_remove("RUSTC_BOOTSTRAP")
        .args([
            "doc",
            "--quiet",
            "--workspace",
            "--exclude",
            "xtask",
            "--no-deps",
            "--lib",
            "--target-dir",
        ])
        .arg(&target)
        .output()
        .context("running cargo doc")?;
    let stderr = String::from_utf8_lossy(&output.stderr);
    if !output.status.success() {
        bail!("cargo doc (rustdoc JSON) failed:\n{stderr}");
    }
    // The documentation a user reads is part of the API: a broken or ambiguous link fails
    // here, in the tests, as clippy does not run in CI.
    if stderr.contains("warning") {
        bail!("cargo doc printed warnings:\n{stderr}");
    }
    Ok(target.join("doc"))
}

/// The rustdoc JSON of one crate, from the folder [`rustdoc_json`] filled.
fn read_rustdoc_json(docs: &Path, krate: &str) -> anyhow::Result<Value> {
    let file = docs.join(format!("{}.json", krate.replace('-', "_")));
    let text =
        std::fs::read_to_string(&file).with_context(|| format!("reading {}", file.display()))?;
    serde_json::from_str(&text).with_context(|| format!("parsing {}", file.display()))
}

/// A script that runs the toolchain's rustdoc with `RUSTC_BOOTSTRAP=1`.
fn rustdoc_wrapper(target: &Path) -> anyhow::Result<PathBuf> {
    let rustdoc = std::env::var("RUSTDOC").unwrap_or_else(|_| "rustdoc".into());
    let dir = target.join("api");
    std::fs::create_dir_all(&dir)?;
    // One file per process, so that concurrent runs never execute a half-written script.
    let path = dir.join(format!("rustdoc-json-{}.sh", std::process::id()));
    std::fs::write(
        &path,
        format!("#!/bin/sh\nRUSTC_BOOTSTRAP=1 exec '{rustdoc}' \"$@\"\n"),
    )?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755))?;
    }
    Ok(path)
}

/// The sorted API lines of one crate's rustdoc JSON.
pub fn render(doc: &Value) -> anyhow::Result<Vec<String>> {
    let root = doc["root"].clone();
    let crate_name = doc["index"][id_key(&root)]["name"]
        .as_str()
        .context("the root item has no name")?
        .to_string();
    let mut api = Api {
        doc,
        lines: BTreeSet::new(),
        walked: HashSet::new(),
    };
    api.module(&root, &crate_name);
    Ok(api.lines.into_iter().collect())
}

/// The key of an id in `index` and `paths` (ids are numbers in the format, keys strings).
fn id_key(id: &Value) -> String {
    match id {
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

struct Api<'a> {
    doc: &'a Value,
    lines: BTreeSet<String>,
    /// Modules already walked under a path, so glob cycles end.
    walked: HashSet<(String, String)>,
}

impl Api<'_> {
    fn item(&self, id: &Value) -> Option<&Value> {
        self.doc["index"].get(id_key(id))
    }

    fn module(&mut self, id: &Value, path: &str) {
        if !self.walked.insert((id_key(id), path.to_string())) {
            return;
        }
        let Some(module) = self.item(id).map(|m| m["inner"]["module"].clone()) else {
            return;
        };
        for child in module["items"].as_array().into_iter().flatten() {
            let Some(item) = self.item(child).cloned() else {
                continue;
            };
            let name = item["name"].as_str().unwrap_or("_").to_string();
            let inner = &item["inner"];
            if let Some(reexport) = inner.get("use") {
                self.reexport(reexport, path);
            } else if inner.get("module").is_some() {
                self.module(child, &format!("{path}::{name}"));
            } else {
                self.declaration(&item, &format!("{path}::{name}"));
            }
        }
    }

    fn reexport(&mut self, reexport: &Value, path: &str) {
        let name = reexport["name"].as_str().unwrap_or("_");
        let source = reexport["source"].as_str().unwrap_or("?");
        let target = reexport.get("id").filter(|t| !t.is_null());
        let local = target.and_then(|t| self.item(t)).cloned();
        match (reexport["is_glob"].as_bool().unwrap_or(false), local) {
            (true, Some(module)) if module["inner"].get("module").is_some() => {
                let id = target.cloned().unwrap_or(Value::Null);
                self.module(&id, path);
            }
            (true, _) => {
                self.lines.insert(format!("pub use {source}::* in {path}"));
            }
            (false, Some(item)) if item["inner"].get("module").is_some() => {
                let id = target.cloned().unwrap_or(Value::Null);
                self.module(&id, &format!("{path}::{name}"));
            }
            (false, Some(item)) => self.declaration(&item, &format!("{path}::{name}")),
            (false, None) => {
                self.lines
                    .insert(format!("pub use {path}::{name} = {source}"));
            }
        }
    }

    fn declaration(&mut self, item: &Value, path: &str) {
        let inner = &item["inner"];
        let Some((kind, body)) = inner.as_object().and_then(|o| o.iter().next()) else {
            return;
        };
        match kind.as_str() {
            "struct" => self.structure(body, path),
            "enum" => self.enumeration(body, path),
            "union" => {
                let generics = self.generics(&body["generics"]);
                self.lines.insert(format!("pub union {path}{generics}"));
            }
            "function" => {
                let line = format!("pub fn {path}{}", self.function(body));
                self.lines.insert(line);
            }
            "trait" => self.trait_item(body, path),
            "constant" => {
                let line = format!("pub const {path}: {}", self.ty(&body["type"]));
                self.lines.insert(line);
            }
            "static" => {
                let line = format!("pub static {path}: {}", self.ty(&body["type"]));
                self.lines.insert(line);
            }
            "type_alias" => {
                let line = format!(
                    "pub type {path}{} = {}",
                    self.generics(&body["generics"]),
                    self.ty(&body["type"])
                );
                self.lines.insert(line);
            }
            "macro" | "proc_macro" => {
                self.lines.insert(format!("macro {path}"));
            }
            other => {
                self.lines.insert(format!("{other} {path}"));
            }
        }
    }

    fn structure(&mut self, body: &Value, path: &str) {
        let generics = self.generics(&body["generics"]);
        let kind = &body["kind"];
        let mut line = format!("pub struct {path}{generics}");
        if let Some(fields) = kind.get("tuple").and_then(Value::as_array) {
            let shown: Vec<String> = fields
                .iter()
                .map(|f| match self.item(f) {
                    Some(field) => self.ty(&field["inner"]["struct_field"]),
                    None => "_".into(),
                })
                .collect();
            line.push_str(&format!("({})", shown.join(", ")));
        } else if let Some(plain) = kind.get("plain") {
            for field in plain["fields"].as_array().into_iter().flatten() {
                if let Some(field) = self.item(field) {
                    let name = field["name"].as_str().unwrap_or("_");
                    let ty = self.ty(&field["inner"]["struct_field"]);
                    self.lines.insert(format!("pub {path}.{name}: {ty}"));
                }
            }
            if plain["has_stripped_fields"].as_bool().unwrap_or(false) {
                line.push_str(" { private fields }");
            }
        }
        self.lines.insert(line);
        self.impls(&body["impls"], path);
    }

    fn enumeration(&mut self, body: &Value, path: &str) {
        let generics = self.generics(&body["generics"]);
        self.lines.insert(format!("pub enum {path}{generics}"));
        for variant in body["variants"].as_array().into_iter().flatten() {
            let Some(variant) = self.item(variant).cloned() else {
                continue;
            };
            let name = variant["name"].as_str().unwrap_or("_");
            let kind = &variant["inner"]["variant"]["kind"];
            let fields = if let Some(fields) = kind.get("tuple").and_then(Value::as_array) {
                let shown: Vec<String> = fields
                    .iter()
                    .map(|f| match self.item(f) {
                        Some(field) => self.ty(&field["inner"]["struct_field"]),
                        None => "_".into(),
                    })
                    .collect();
                format!("({})", shown.join(", "))
            } else if let Some(fields) = kind.get("struct") {
                let shown: Vec<String> = fields["fields"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .filter_map(|f| self.item(f))
                    .map(|field| {
                        format!(
                            "{}: {}",
                            field["name"].as_str().unwrap_or("_"),
                            self.ty(&field["inner"]["struct_field"])
                        )
                    })
                    .collect();
                format!(" {{ {} }}", shown.join(", "))
            } else {
                String::new()
            };
            self.lines.insert(format!("{path}::{name}{fields}"));
        }
        self.impls(&body["impls"], path);
    }

    /// Inherent methods and the traits a type implements (not the auto and blanket ones).
    fn impls(&mut self, impls: &Value, path: &str) {
        for id in impls.as_array().into_iter().flatten() {
            let Some(block) = self.item(id).map(|i| i["inner"]["impl"].clone()) else {
                continue;
            };
            if block["is_synthetic"].as_bool().unwrap_or(false) || !block["blanket_impl"].is_null()
            {
                continue;
            }
            if block["trait"].is_null() {
                for member in block["items"].as_array().into_iter().flatten() {
                    let Some(member) = self.item(member).cloned() else {
                        continue;
                    };
                    if member["visibility"].as_str() != Some("public") {
                        continue;
                    }
                    let name = member["name"].as_str().unwrap_or("_");
                    let inner = &member["inner"];
                    if let Some(function) = inner.get("function") {
                        let line = format!("pub fn {path}::{name}{}", self.function(function));
                        self.lines.insert(line);
                    } else if let Some(constant) = inner.get("assoc_const") {
                        let line =
                            format!("pub const {path}::{name}: {}", self.ty(&constant["type"]));
                        self.lines.insert(line);
                    }
                }
            } else {
                let negative = if block["is_negative"].as_bool().unwrap_or(false) {
                    "!"
                } else {
                    ""
                };
                let line = format!(
                    "impl{} {negative}{} for {}",
                    self.generics(&block["generics"]),
                    self.path(&block["trait"]),
                    self.ty(&block["for"])
                );
                self.lines.insert(line);
            }
        }
    }

    fn trait_item(&mut self, body: &Value, path: &str) {
        let bounds = self.bounds(&body["bounds"]);
        let bounds = if bounds.is_empty() {
            String::new()
        } else {
            format!(": {bounds}")
        };
        let line = format!(
            "pub trait {path}{}{bounds}",
            self.generics(&body["generics"])
        );
        self.lines.insert(line);
        for member in body["items"].as_array().into_iter().flatten() {
            let Some(member) = self.item(member).cloned() else {
                continue;
            };
            let name = member["name"].as_str().unwrap_or("_");
            let inner = &member["inner"];
            let line = if let Some(function) = inner.get("function") {
                let provided = if function["has_body"].as_bool().unwrap_or(false) {
                    " (provided)"
                } else {
                    ""
                };
                format!("fn {path}::{name}{}{provided}", self.function(function))
            } else if let Some(assoc) = inner.get("assoc_type") {
                let bounds = self.bounds(&assoc["bounds"]);
                format!("type {path}::{name}: {bounds}")
            } else if let Some(assoc) = inner.get("assoc_const") {
                format!("const {path}::{name}: {}", self.ty(&assoc["type"]))
            } else {
                format!("item {path}::{name}")
            };
            self.lines.insert(line);
        }
    }

    /// `<generics>(inputs) -> output where …` of a function.
    fn function(&self, function: &Value) -> String {
        let header = &function["header"];
        let mut prefix = String::new();
        for (key, word) in [
            ("is_const", "const "),
            ("is_async", "async "),
            ("is_unsafe", "unsafe "),
        ] {
            if header[key].as_bool().unwrap_or(false) {
                prefix.push_str(word);
            }
        }
        let sig = &function["sig"];
        let inputs: Vec<String> = sig["inputs"]
            .as_array()
            .into_iter()
            .flatten()
            .map(|pair| {
                let name = pair[0].as_str().unwrap_or("_");
                let ty = self.ty(&pair[1]);
                match (name, ty.as_str()) {
                    ("self", "Self") => "self".to_string(),
                    ("self", "&Self") => "&self".to_string(),
                    ("self", "&mut Self") => "&mut self".to_string(),
                    _ => format!("{name}: {ty}"),
                }
            })
            .collect();
        let output = if sig["output"].is_null() {
            String::new()
        } else {
            format!(" -> {}", self.ty(&sig["output"]))
        };
        let generics = self.generics(&function["generics"]);
        let prefix = if prefix.is_empty() {
            String::new()
        } else {
            format!(" [{}]", prefix.trim_end())
        };
        format!(
            "{generics}({}){output}{}{prefix}",
            inputs.join(", "),
            self.where_clause(&function["generics"])
        )
    }

    fn generics(&self, generics: &Value) -> String {
        let params: Vec<String> = generics["params"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|p| {
                let name = p["name"].as_str().unwrap_or("_");
                let kind = &p["kind"];
                if let Some(ty) = kind.get("type") {
                    if ty["is_synthetic"].as_bool().unwrap_or(false) {
                        return None;
                    }
                    let bounds = self.bounds(&ty["bounds"]);
                    Some(if bounds.is_empty() {
                        name.to_string()
                    } else {
                        format!("{name}: {bounds}")
                    })
                } else if let Some(constant) = kind.get("const") {
                    Some(format!("const {name}: {}", self.ty(&constant["type"])))
                } else {
                    Some(name.to_string())
                }
            })
            .collect();
        if params.is_empty() {
            String::new()
        } else {
            format!("<{}>", params.join(", "))
        }
    }

    fn where_clause(&self, generics: &Value) -> String {
        let predicates: Vec<String> = generics["where_predicates"]
            .as_array()
            .into_iter()
            .flatten()
            .map(|p| {
                if let Some(bound) = p.get("bound_predicate") {
                    format!(
                        "{}: {}",
                        self.ty(&bound["type"]),
                        self.bounds(&bound["bounds"])
                    )
                } else {
                    p.to_string()
                }
            })
            .collect();
        if predicates.is_empty() {
            String::new()
        } else {
            format!(" where {}", predicates.join(", "))
        }
    }

    fn bounds(&self, bounds: &Value) -> String {
        let shown: Vec<String> = bounds
            .as_array()
            .into_iter()
            .flatten()
            .map(|b| {
                if let Some(bound) = b.get("trait_bound") {
                    let maybe = if bound["modifier"].as_str() == Some("maybe") {
                        "?"
                    } else {
                        ""
                    };
                    format!("{maybe}{}", self.path(&bound["trait"]))
                } else if let Some(lifetime) = b.get("outlives") {
                    lifetime.as_str().unwrap_or("'_").to_string()
                } else {
                    b.to_string()
                }
            })
            .collect();
        shown.join(" + ")
    }

    /// A path with its generic arguments, named as the module doc says.
    fn path(&self, path: &Value) -> String {
        let name = self.name_of(path);
        match path.get("args").filter(|a| !a.is_null()) {
            Some(args) => format!("{name}{}", self.args(args)),
            None => name,
        }
    }

    fn name_of(&self, path: &Value) -> String {
        let written = path["path"].as_str().unwrap_or("?");
        let last = written.rsplit("::").next().unwrap_or(written).to_string();
        let Some(summary) = path
            .get("id")
            .and_then(|id| self.doc["paths"].get(id_key(id)))
        else {
            return last;
        };
        let crate_id = summary["crate_id"].as_u64().unwrap_or(0);
        let segments: Vec<&str> = summary["path"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(Value::as_str)
            .collect();
        let first = segments.first().copied().unwrap_or("");
        let last = segments.last().map(|s| s.to_string()).unwrap_or(last);
        if crate_id == 0 || matches!(first, "std" | "core" | "alloc") {
            last
        } else {
            format!("{first}::{last}")
        }
    }

    fn args(&self, args: &Value) -> String {
        if let Some(angle) = args.get("angle_bracketed") {
            let mut shown: Vec<String> = angle["args"]
                .as_array()
                .into_iter()
                .flatten()
                .map(|a| {
                    if let Some(ty) = a.get("type") {
                        self.ty(ty)
                    } else if let Some(lifetime) = a.get("lifetime") {
                        lifetime.as_str().unwrap_or("'_").to_string()
                    } else if let Some(constant) = a.get("const") {
                        constant["expr"].as_str().unwrap_or("_").to_string()
                    } else {
                        "_".to_string()
                    }
                })
                .collect();
            for constraint in angle["constraints"].as_array().into_iter().flatten() {
                let name = constraint["name"].as_str().unwrap_or("_");
                let binding = &constraint["binding"];
                if let Some(equality) = binding.get("equality") {
                    let value = equality
                        .get("type")
                        .map(|t| self.ty(t))
                        .unwrap_or_else(|| equality.to_string());
                    shown.push(format!("{name} = {value}"));
                } else if let Some(bounds) = binding.get("constraint") {
                    shown.push(format!("{name}: {}", self.bounds(bounds)));
                }
            }
            if shown.is_empty() {
                String::new()
            } else {
                format!("<{}>", shown.join(", "))
            }
        } else if let Some(paren) = args.get("parenthesized") {
            let inputs: Vec<String> = paren["inputs"]
                .as_array()
                .into_iter()
                .flatten()
                .map(|t| self.ty(t))
                .collect();
            let output = if paren["output"].is_null() {
                String::new()
            } else {
                format!(" -> {}", self.ty(&paren["output"]))
            };
            format!("({}){output}", inputs.join(", "))
        } else {
            String::new()
        }
    }

    fn ty(&self, ty: &Value) -> String {
        let Some((kind, body)) = ty.as_object().and_then(|o| o.iter().next()) else {
            return ty.as_str().unwrap_or("?").to_string();
        };
        match kind.as_str() {
            "resolved_path" => self.path(body),
            "generic" | "primitive" => body.as_str().unwrap_or("?").to_string(),
            "borrowed_ref" => {
                let lifetime = body["lifetime"]
                    .as_str()
                    .map(|l| format!("{l} "))
                    .unwrap_or_default();
                let mutable = if body["is_mutable"].as_bool().unwrap_or(false) {
                    "mut "
                } else {
                    ""
                };
                format!("&{lifetime}{mutable}{}", self.ty(&body["type"]))
            }
            "raw_pointer" => {
                let mutable = if body["is_mutable"].as_bool().unwrap_or(false) {
                    "mut"
                } else {
                    "const"
                };
                format!("*{mutable} {}", self.ty(&body["type"]))
            }
            "slice" => format!("[{}]", self.ty(body)),
            "array" => format!(
                "[{}; {}]",
                self.ty(&body["type"]),
                body["len"].as_str().unwrap_or("_")
            ),
            "tuple" => {
                let items: Vec<String> = body
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|t| self.ty(t))
                    .collect();
                format!("({})", items.join(", "))
            }
            "impl_trait" => format!("impl {}", self.bounds(body)),
            "dyn_trait" => {
                let traits: Vec<String> = body["traits"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|t| self.path(&t["trait"]))
                    .collect();
                let lifetime = body["lifetime"]
                    .as_str()
                    .map(|l| format!(" + {l}"))
                    .unwrap_or_default();
                format!("dyn {}{lifetime}", traits.join(" + "))
            }
            "qualified_path" => format!(
                "<{} as {}>::{}",
                self.ty(&body["self_type"]),
                self.path(&body["trait"]),
                body["name"].as_str().unwrap_or("_")
            ),
            "function_pointer" => {
                let sig = &body["sig"];
                let inputs: Vec<String> = sig["inputs"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|pair| self.ty(&pair[1]))
                    .collect();
                let output = if sig["output"].is_null() {
                    String::new()
                } else {
                    format!(" -> {}", self.ty(&sig["output"]))
                };
                format!("fn({}){output}", inputs.join(", "))
            }
            "infer" => "_".to_string(),
            other => format!("{other}?"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The public API of every library crate is the one recorded under `api/`: a change of the
    /// API must come with its snapshot (`cargo xtask api --bless`).
    #[test]
    fn the_public_api_is_the_recorded_one() {
        let differences = check(&workspace_root(), false).unwrap();
        assert!(differences.is_empty(), "{}", differences.join("\n"));
    }

    /// The renderer on a hand-made rustdoc document: a re-export, a struct with a public field
    /// and a method, a trait impl, a generic function.
    #[test]
    fn rendering_shows_paths_fields_methods_and_signatures() {
        let doc = serde_json::json!({
            "root": 0,
            "index": {
                "0": {"name": "demo", "inner": {"module": {"items": [1, 5, 7]}}},
                "1": {"name": "Thing", "visibility": "public", "inner": {"struct": {
                    "generics": {"params": [], "where_predicates": []},
                    "kind": {"plain": {"fields": [2], "has_stripped_fields": true}},
                    "impls": [3, 6]}}},
                "2": {"name": "size", "inner": {"struct_field": {"primitive": "usize"}}},
                "3": {"name": null, "inner": {"impl": {"is_synthetic": false, "blanket_impl": null,
                    "trait": null, "generics": {"params": [], "where_predicates": []},
                    "for": {"resolved_path": {"path": "Thing", "id": 1, "args": null}},
                    "items": [4], "is_negative": false}}},
                "4": {"name": "grow", "visibility": "public", "inner": {"function": {
                    "header": {"is_const": false, "is_async": false, "is_unsafe": false},
                    "generics": {"params": [], "where_predicates": []},
                    "sig": {"inputs": [["self", {"borrowed_ref": {"lifetime": null, "is_mutable": true,
                        "type": {"generic": "Self"}}}], ["by", {"primitive": "f64"}]],
                        "output": {"resolved_path": {"path": "Option", "id": 20,
                            "args": {"angle_bracketed": {"args": [{"type": {"primitive": "u8"}}],
                            "constraints": []}}}}}}}},
                "5": {"name": null, "inner": {"use": {"source": "nalgebra", "name": "nalgebra",
                    "id": 21, "is_glob": false}}},
                "6": {"name": null, "inner": {"impl": {"is_synthetic": false, "blanket_impl": null,
                    "trait": {"path": "Clone", "id": 22, "args": null},
                    "generics": {"params": [], "where_predicates": []},
                    "for": {"resolved_path": {"path": "Thing", "id": 1, "args": null}},
                    "items": [], "is_negative": false}}},
                "7": {"name": "first", "visibility": "public", "inner": {"function": {
                    "header": {"is_const": false, "is_async": false, "is_unsafe": false},
                    "generics": {"params": [{"name": "T", "kind": {"type": {"bounds": [
                        {"trait_bound": {"trait": {"path": "Copy", "id": 23, "args": null},
                        "generic_params": [], "modifier": "none"}}],
                        "default": null, "is_synthetic": false}}}], "where_predicates": []},
                    "sig": {"inputs": [["items", {"borrowed_ref": {"lifetime": null, "is_mutable": false,
                        "type": {"slice": {"generic": "T"}}}}]],
                        "output": {"generic": "T"}}}}}
            },
            "paths": {
                "20": {"crate_id": 2, "path": ["core", "option", "Option"], "kind": "enum"},
                "21": {"crate_id": 5, "path": ["nalgebra"], "kind": "module"},
                "22": {"crate_id": 2, "path": ["core", "clone", "Clone"], "kind": "trait"},
                "23": {"crate_id": 2, "path": ["core", "marker", "Copy"], "kind": "trait"}
            }
        });
        let lines = render(&doc).unwrap();
        assert_eq!(
            lines,
            [
                "impl Clone for Thing",
                "pub demo::Thing.size: usize",
                "pub fn demo::Thing::grow(&mut self, by: f64) -> Option<u8>",
                "pub fn demo::first<T: Copy>(items: &[T]) -> T",
                "pub struct demo::Thing { private fields }",
                "pub use demo::nalgebra = nalgebra",
            ]
        );
    }
}
