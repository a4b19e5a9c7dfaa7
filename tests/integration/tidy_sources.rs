//! The invariants of ARCHITECTURE.md that a scan of the sources checks (`tidy` checks those of
//! `cargo metadata`): no file of a crate imports one that imports it back, file formats are
//! read and written in `timesift-io` only, the root's modules stay small unless they say why,
//! and ARCHITECTURE.md names every crate and, for every invariant, the test that checks it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The `src` folder of every crate of the workspace (the root package's included), by name.
fn crate_sources() -> BTreeMap<String, PathBuf> {
    let mut crates = BTreeMap::from([("timesift".to_string(), root().join("src"))]);
    for entry in std::fs::read_dir(root().join("crates")).expect("crates/") {
        let dir = entry.expect("entry").path();
        let name = format!(
            "timesift-{}",
            dir.file_name().expect("name").to_string_lossy()
        );
        crates.insert(name, dir.join("src"));
    }
    crates
}

/// Every `.rs` file below `dir`, sorted.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    let mut dirs = vec![dir.to_path_buf()];
    while let Some(d) = dirs.pop() {
        for entry in std::fs::read_dir(&d).expect("a source folder") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

/// The shipped code of a file: without its comments and without the `#[cfg(test)]` module
/// that closes it.
fn shipped_code(text: &str) -> String {
    let mut out = String::new();
    let mut lines = text.lines().peekable();
    while let Some(line) = lines.next() {
        let trimmed = line.trim_start();
        if trimmed.starts_with("#[cfg(test)]")
            && lines
                .peek()
                .is_some_and(|next| next.trim_start().starts_with("mod "))
        {
            break;
        }
        if trimmed.starts_with("//") {
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

/// The module path of a source file: `[]` for the crate root, `["a", "b"]` for `a/b.rs` or
/// `a/b/mod.rs`.
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let relative = file.strip_prefix(src).expect("below src");
    let mut parts: Vec<String> = relative
        .iter()
        .map(|p| p.to_string_lossy().trim_end_matches(".rs").to_string())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

/// The paths a `use` tree names, expanded (`a::{b, c::d}` → `a::b`, `a::c::d`).
fn expand_use(tree: &str) -> Vec<String> {
    let tree: String = tree.chars().filter(|c| !c.is_whitespace()).collect();
    let Some(open) = tree.find('{') else {
        return vec![tree];
    };
    let prefix = &tree[..open];
    let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
    // Split the inside at the commas of depth 0.
    let (mut depth, mut start, mut parts) = (0, 0, Vec::new());
    for (i, c) in inner.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&inner[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push(&inner[start..]);
    parts
        .into_iter()
        .filter(|p| !p.is_empty())
        .flat_map(|p| expand_use(&format!("{prefix}{p}")))
        .collect()
}

/// A file of a crate: its module path, the paths of the crate's own items (`crate::`,
/// `super::`, `self::`) its private `use`s and its code name, and what it re-exports
/// (`pub use`).
struct SourceFile {
    module: Vec<String>,
    uses: Vec<Vec<String>>,
    reexports: BTreeMap<String, Vec<String>>,
}

/// `path` (segments after `crate`, `super` or `self`) as an absolute module path, from `module`.
fn absolute(module: &[String], path: &str) -> Option<Vec<String>> {
    let mut segments = path
        .split("::")
        .map(|s| s.trim_end_matches(" as _").to_string());
    let first = segments.next()?;
    let mut base: Vec<String> = match first.as_str() {
        "crate" => Vec::new(),
        "self" => module.to_vec(),
        "super" => {
            // `super` of module a::b (`a/b.rs` or `a/b/mod.rs`) is `a`.
            let mut m = module.to_vec();
            m.pop();
            m
        }
        _ => return None,
    };
    for s in segments {
        if s == "super" {
            base.pop();
        } else {
            let name = s.split(" as ").next().unwrap_or("").to_string();
            base.push(name);
        }
    }
    Some(base)
}

fn parse_source(src: &Path, file: &Path) -> SourceFile {
    let text = std::fs::read_to_string(file).expect("a source file");
    let code = shipped_code(&text);
    let module = module_of(src, file);
    let mut uses = Vec::new();
    let mut reexports = BTreeMap::new();
    // `use` declarations, to their semicolon.
    let mut rest = code.as_str();
    while let Some(at) = rest.find("use ") {
        let before = &rest[..at];
        let line_start = before.rfind('\n').map_or(0, |i| i + 1);
        let head = rest[line_start..at].trim();
        let end = rest[at..].find(';').map_or(rest.len(), |e| at + e);
        let is_decl = head.is_empty() || head.starts_with("pub");
        if is_decl {
            for path in expand_use(&rest[at + 4..end]) {
                let Some(target) = absolute(&module, &path) else {
                    continue;
                };
                if head.starts_with("pub") {
                    if let Some(name) = target.last() {
                        reexports.insert(name.clone(), target.clone());
                    }
                } else {
                    uses.push(target);
                }
            }
        }
        rest = &rest[end.min(rest.len())..];
        if rest.len() <= 1 {
            break;
        }
        rest = &rest[1..];
    }
    // Paths in code (`crate::a::f(…)`, `super::b::T`).
    for prefix in ["crate::", "super::"] {
        for (at, _) in code.match_indices(prefix) {
            let preceding = code[..at].chars().next_back();
            if preceding.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            let path: String = code[at..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                .collect();
            if let Some(target) = absolute(&module, path.trim_end_matches(':')) {
                uses.push(target);
            }
        }
    }
    SourceFile {
        module,
        uses,
        reexports,
    }
}

/// The file that defines what `path` names: the deepest module on the path, through the
/// re-exports of facade modules.
fn defining_module(files: &BTreeMap<Vec<String>, SourceFile>, path: &[String]) -> Vec<String> {
    let mut path = path.to_vec();
    for _ in 0..16 {
        let depth = (0..=path.len())
            .rev()
            .find(|&d| files.contains_key(&path[..d]))
            .unwrap_or(0);
        let module = path[..depth].to_vec();
        let Some(name) = path.get(depth) else {
            return module;
        };
        match files[&module].reexports.get(name) {
            Some(target) if *target != path => {
                let mut next = target.clone();
                next.extend(path[depth + 1..].iter().cloned());
                path = next;
            }
            _ => return module,
        }
    }
    path
}

/// A cycle of imports among `files`, as module paths, if there is one.
fn import_cycle(files: &BTreeMap<Vec<String>, SourceFile>) -> Option<Vec<String>> {
    let edges: BTreeMap<&Vec<String>, BTreeSet<Vec<String>>> = files
        .iter()
        .map(|(m, f)| {
            let targets = f
                .uses
                .iter()
                .map(|u| defining_module(files, u))
                // A file may use what its own ancestors define, as a submodule sees its
                // parent's scope: only the other edges can close a cycle.
                .filter(|t| t != m && !m.starts_with(t))
                .collect();
            (m, targets)
        })
        .collect();
    // Depth-first search with colours.
    fn visit<'a>(
        m: &'a Vec<String>,
        edges: &'a BTreeMap<&'a Vec<String>, BTreeSet<Vec<String>>>,
        state: &mut BTreeMap<&'a Vec<String>, u8>,
        stack: &mut Vec<&'a Vec<String>>,
    ) -> Option<Vec<String>> {
        state.insert(m, 1);
        stack.push(m);
        for t in edges.get(m).into_iter().flatten() {
            let Some((key, _)) = edges.get_key_value(t) else {
                continue;
            };
            match state.get(key) {
                Some(1) => {
                    let from = stack.iter().position(|s| *s == t).unwrap_or(0);
                    let mut cycle: Vec<String> = stack[from..]
                        .iter()
                        .map(|s| format!("crate::{}", s.join("::")))
                        .collect();
                    cycle.push(format!("crate::{}", t.join("::")));
                    return Some(cycle);
                }
                Some(_) => {}
                None => {
                    if let Some(c) = visit(key, edges, state, stack) {
                        return Some(c);
                    }
                }
            }
        }
        stack.pop();
        state.insert(m, 2);
        None
    }
    let mut state = BTreeMap::new();
    for m in edges.keys() {
        if !state.contains_key(m)
            && let Some(c) = visit(m, &edges, &mut state, &mut Vec::new())
        {
            return Some(c);
        }
    }
    None
}

/// No file of a crate imports (by `use` or by a path in its code) a file that imports it back,
/// directly or through others: each crate's files form a hierarchy, readable bottom up.
/// Re-exports (`pub use`) are not imports: a path through a facade counts as an import of the
/// file that defines the item. A file may use its ancestors' items (a submodule sees its
/// parent's scope).
#[test]
fn no_file_of_a_crate_imports_one_that_imports_it() {
    let mut cycles = Vec::new();
    for (name, src) in crate_sources() {
        let files: BTreeMap<Vec<String>, SourceFile> = rust_files(&src)
            .iter()
            .map(|f| parse_source(&src, f))
            .map(|f| (f.module.clone(), f))
            .collect();
        if let Some(cycle) = import_cycle(&files) {
            cycles.push(format!("{name}: {}", cycle.join(" → ")));
        }
    }
    assert!(cycles.is_empty(), "import cycles:\n{}", cycles.join("\n"));
}

/// The import graph sees a cycle where there is one, and follows a facade's re-export to the
/// defining file.
#[test]
fn the_import_scan_finds_a_cycle_and_follows_re_exports() {
    let file = |module: &[&str], uses: &[&[&str]], reexports: &[(&str, &[&str])]| {
        let owned = |p: &[&str]| p.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        (
            owned(module),
            SourceFile {
                module: owned(module),
                uses: uses.iter().map(|u| owned(u)).collect(),
                reexports: reexports
                    .iter()
                    .map(|(n, t)| (n.to_string(), owned(t)))
                    .collect(),
            },
        )
    };
    // lib re-exports Error from error.rs; a uses it through the facade, b uses a: no cycle.
    let files = BTreeMap::from([
        file(&[], &[&["a", "run"]], &[("Error", &["error", "Error"])]),
        file(&["error"], &[], &[]),
        file(&["a"], &[&["Error"], &["b", "f"]], &[]),
        file(&["b"], &[&["error", "Error"]], &[]),
    ]);
    assert_eq!(import_cycle(&files), None);
    // b now uses a back.
    let mut cyclic = files;
    cyclic.insert(
        file(&["b"], &[&["a", "g"]], &[]).0,
        file(&["b"], &[&["a", "g"]], &[]).1,
    );
    assert!(import_cycle(&cyclic).is_some());
    assert_eq!(
        expand_use("crate::{a::{B, C}, d}"),
        ["crate::a::B", "crate::a::C", "crate::d"]
    );
}

/// Code that encodes or decodes a file format (images, rasters, point clouds, CSV), outside
/// `timesift-io`, with the reason each exception stands.
const FORMAT_EXCEPTIONS: [(&str, &str); 3] = [
    (
        "crates/synth/src/writer.rs",
        "renders the scenes' images as JPEG, PNG or TIFF: synth writes projects and knows no \
         stage, and must not depend on io's readers to write what they read",
    ),
    (
        "crates/matching/src/storage.rs",
        "the .feat and .match work files are the matching stage's own cache, written and read \
         only by it (checksummed binary)",
    ),
    (
        "crates/features/src/text.rs",
        "the feature text format of docs/design.md is the features crate's public exchange \
         format (OpenCV and COLMAP benches read and write it)",
    ),
];

/// No file outside `timesift-io` encodes or decodes a file format, bar the stated exceptions:
/// no image codec, no CSV, TIFF, EXR or LAS crate, no line split at commas. File access for
/// the root's own JSON and TOML and for fingerprints is not a format.
#[test]
fn no_file_outside_io_encodes_or_decodes_a_file_format() {
    let patterns = [
        "image::codecs",
        "ImageEncoder",
        "ImageDecoder",
        "csv::",
        "tiff::",
        "exr::",
        "las::",
        "laz::",
        "split(',')",
    ];
    let mut found = Vec::new();
    for (name, src) in crate_sources() {
        if name == "timesift-io" {
            continue;
        }
        for file in rust_files(&src) {
            let relative = file.strip_prefix(root()).expect("below the root");
            let relative = relative.to_string_lossy().replace('\\', "/");
            if FORMAT_EXCEPTIONS.iter().any(|(f, _)| *f == relative) {
                continue;
            }
            let code = shipped_code(&std::fs::read_to_string(&file).expect("source"));
            for p in patterns.iter().filter(|p| names_path(&code, p)) {
                found.push(format!("{relative}: {p}"));
            }
        }
    }
    assert!(
        found.is_empty(),
        "file formats belong to timesift-io:\n{}",
        found.join("\n")
    );
    for (file, reason) in FORMAT_EXCEPTIONS {
        assert!(root().join(file).is_file(), "{file} no longer exists");
        assert!(!reason.is_empty());
    }
    // The scan itself: a crate's own path is seen, a longer name or io's module is not.
    assert!(names_path(
        "let d = tiff::decoder::Decoder::new(f);",
        "tiff::"
    ));
    assert!(names_path("line.split(',')", "split(',')"));
    assert!(!names_path("use timesift_io::geotiff::read_f32;", "tiff::"));
    assert!(!names_path(
        "timesift_io::exr::read_f32_channels(p)",
        "exr::"
    ));
}

/// Whether `code` holds `pattern` as a path of its own: `tiff::` but neither `geotiff::` nor
/// io's own module (`timesift_io::exr::`).
fn names_path(code: &str, pattern: &str) -> bool {
    code.match_indices(pattern).any(|(at, _)| {
        !code[..at]
            .chars()
            .next_back()
            .is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':')
    })
}

/// Largest module of the root package, lines of shipped code (comments and tests apart), unless
/// its first lines say why it is larger (`//! Long module: …`).
const MAX_ROOT_MODULE_LINES: usize = 700;

/// The root is an orchestrator: its modules stay small, or say why not.
#[test]
fn the_root_holds_no_large_module_without_a_reason() {
    let mut large = Vec::new();
    for file in rust_files(&root().join("src")) {
        let text = std::fs::read_to_string(&file).expect("source");
        let lines = shipped_code(&text)
            .lines()
            .filter(|l| !l.trim().is_empty())
            .count();
        let reason = text
            .lines()
            .take_while(|l| l.starts_with("//!"))
            .any(|l| l.starts_with("//! Long module: "));
        if lines > MAX_ROOT_MODULE_LINES && !reason {
            large.push(format!("{}: {lines} lines", file.display()));
        }
    }
    assert!(
        large.is_empty(),
        "root modules over {MAX_ROOT_MODULE_LINES} lines of code without a `//! Long module:` \
         reason:\n{}",
        large.join("\n")
    );
}

/// Every test function of the workspace, by name.
fn test_names() -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    let mut dirs = vec![root().join("tests")];
    for src in crate_sources().values() {
        dirs.push(src.clone());
        dirs.push(src.with_file_name("tests"));
    }
    for dir in dirs.into_iter().filter(|d| d.is_dir()) {
        for file in rust_files(&dir) {
            let text = std::fs::read_to_string(&file).expect("source");
            let mut lines = text.lines();
            while let Some(line) = lines.next() {
                if !line.trim_start().starts_with("#[test]") {
                    continue;
                }
                // The function follows its attributes.
                for next in lines.by_ref() {
                    if let Some(rest) = next.trim_start().strip_prefix("fn ") {
                        let name: String = rest
                            .chars()
                            .take_while(|c| c.is_alphanumeric() || *c == '_')
                            .collect();
                        names.insert(name);
                        break;
                    }
                }
            }
        }
    }
    names
}

/// ARCHITECTURE.md names every crate in its table, and every invariant there names the test
/// that checks it (`` [test: `name`] ``), which exists.
#[test]
fn architecture_names_every_crate_and_the_test_of_every_invariant() {
    let text = std::fs::read_to_string(root().join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let rows: Vec<&str> = text.lines().filter(|l| l.starts_with("| `")).collect();
    let tests = test_names();
    let mut problems = Vec::new();
    for name in crate_sources().keys().map(String::as_str).chain(["xtask"]) {
        let Some(row) = rows.iter().find(|r| r.starts_with(&format!("| `{name}`"))) else {
            problems.push(format!("{name}: no row in the crate table"));
            continue;
        };
        let invariants = row.rsplit('|').nth(1).unwrap_or("");
        let named: Vec<&str> = invariants
            .split("[test: `")
            .skip(1)
            .filter_map(|s| s.split('`').next())
            .collect();
        if named.is_empty() {
            problems.push(format!("{name}: its invariants name no test"));
        }
        for t in named.iter().filter(|t| !tests.contains(**t)) {
            problems.push(format!("{name}: test `{t}` does not exist"));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
