//! `cargo xtask fn-lengths`: the functions longer than a bound in the shipped code, so that a
//! reviewer's "62 functions over 100 lines" is a command, not an impression.
//!
//! What counts: every `fn` with a body (free functions, methods, trait defaults, nested
//! functions each on their own) in `src/` of the root package and of every crate under
//! `crates/`, from its `fn` line to its closing brace. Test code is left out: `tests/`,
//! `benches/`, `examples/`, items under `#[cfg(test)]` and `#[test]` functions; so is `xtask`.
//! Files are parsed with `syn`, so braces in strings and comments do not count.
//!
//! A long function may stay when a plain comment above its signature says why, starting with
//! [`JUSTIFICATION`]; the table marks those, and `--check` fails on any other.

use std::path::{Path, PathBuf};

use anyhow::Context;
use syn::spanned::Spanned;
use syn::visit::Visit;

/// The start of the comment that justifies a long function (`// Long function: why`).
pub const JUSTIFICATION: &str = "// Long function:";

/// A function over the bound.
pub struct LongFunction {
    /// Path from the workspace root.
    pub file: PathBuf,
    /// Line of its `fn` keyword.
    pub line: usize,
    /// Its name (`Type::name` for methods).
    pub name: String,
    /// Lines from `fn` to the closing brace.
    pub lines: usize,
    /// The reason written above it, if any.
    pub justification: Option<String>,
}

/// Every function over `max_lines` in the shipped code below `root`, longest first.
pub fn long_functions(root: &Path, max_lines: usize) -> anyhow::Result<Vec<LongFunction>> {
    let mut found = Vec::new();
    for file in shipped_sources(root)? {
        let text = std::fs::read_to_string(root.join(&file))
            .with_context(|| format!("{}: cannot read", file.display()))?;
        let syntax = syn::parse_file(&text)
            .with_context(|| format!("{}: not valid Rust", file.display()))?;
        let lines: Vec<&str> = text.lines().collect();
        let mut visitor = Lengths {
            lines: &lines,
            owner: None,
            spans: Vec::new(),
        };
        visitor.visit_file(&syntax);
        for span in visitor.spans {
            if span.lines > max_lines {
                found.push(LongFunction {
                    file: file.clone(),
                    line: span.line,
                    name: span.name,
                    lines: span.lines,
                    justification: span.justification,
                });
            }
        }
    }
    found.sort_by(|a, b| b.lines.cmp(&a.lines).then(a.file.cmp(&b.file)));
    Ok(found)
}

/// `src/**/*.rs` of the root package and of every crate, relative to `root`, sorted.
fn shipped_sources(root: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut dirs = vec![PathBuf::from("src")];
    let crates = root.join("crates");
    for entry in std::fs::read_dir(&crates).with_context(|| crates.display().to_string())? {
        let name = entry?.file_name();
        dirs.push(Path::new("crates").join(name).join("src"));
    }
    let mut files = Vec::new();
    while let Some(dir) = dirs.pop() {
        let Ok(entries) = std::fs::read_dir(root.join(&dir)) else {
            continue;
        };
        for entry in entries {
            let entry = entry?;
            let path = dir.join(entry.file_name());
            if entry.file_type()?.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                files.push(path);
            }
        }
    }
    files.sort();
    Ok(files)
}

struct FnSpan {
    name: String,
    line: usize,
    lines: usize,
    justification: Option<String>,
}

struct Lengths<'a> {
    lines: &'a [&'a str],
    /// The type of the `impl` or trait being visited.
    owner: Option<String>,
    spans: Vec<FnSpan>,
}

impl Lengths<'_> {
    fn record(&mut self, name: &syn::Ident, item_start: usize, fn_line: usize, end: usize) {
        let name = match &self.owner {
            Some(owner) => format!("{owner}::{name}"),
            None => name.to_string(),
        };
        // The justification stands between the item's first line (its doc comment) and its
        // signature, or on the line just above both.
        let from = item_start.saturating_sub(2);
        let justification = self.lines[from..fn_line.min(self.lines.len())]
            .iter()
            .find_map(|l| l.trim().strip_prefix(JUSTIFICATION))
            .map(|reason| reason.trim().to_string());
        self.spans.push(FnSpan {
            name,
            line: fn_line,
            lines: end + 1 - fn_line,
            justification,
        });
    }
}

fn is_test(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| {
        a.path().is_ident("test")
            || (a.path().is_ident("cfg")
                && a.meta
                    .require_list()
                    .is_ok_and(|l| l.tokens.to_string().split(',').any(|t| t.trim() == "test")))
    })
}

impl<'ast> Visit<'ast> for Lengths<'_> {
    fn visit_item_mod(&mut self, item: &'ast syn::ItemMod) {
        if !is_test(&item.attrs) {
            syn::visit::visit_item_mod(self, item);
        }
    }

    fn visit_item_fn(&mut self, item: &'ast syn::ItemFn) {
        if is_test(&item.attrs) {
            return;
        }
        let start = item.span().start().line;
        let fn_line = item.sig.fn_token.span.start().line;
        let end = item.block.brace_token.span.close().end().line;
        // A nested function is measured as itself, and within its parent.
        let owner = self.owner.take();
        self.record(&item.sig.ident, start, fn_line, end);
        syn::visit::visit_block(self, &item.block);
        self.owner = owner;
    }

    fn visit_item_impl(&mut self, item: &'ast syn::ItemImpl) {
        if is_test(&item.attrs) {
            return;
        }
        let ty = &item.self_ty;
        let owner = self.owner.replace(quote_type(ty));
        syn::visit::visit_item_impl(self, item);
        self.owner = owner;
    }

    fn visit_item_trait(&mut self, item: &'ast syn::ItemTrait) {
        let owner = self.owner.replace(item.ident.to_string());
        syn::visit::visit_item_trait(self, item);
        self.owner = owner;
    }

    fn visit_impl_item_fn(&mut self, item: &'ast syn::ImplItemFn) {
        if is_test(&item.attrs) {
            return;
        }
        let start = item.span().start().line;
        let fn_line = item.sig.fn_token.span.start().line;
        let end = item.block.brace_token.span.close().end().line;
        self.record(&item.sig.ident, start, fn_line, end);
        syn::visit::visit_block(self, &item.block);
    }

    fn visit_trait_item_fn(&mut self, item: &'ast syn::TraitItemFn) {
        if let Some(block) = &item.default {
            let start = item.span().start().line;
            let fn_line = item.sig.fn_token.span.start().line;
            let end = block.brace_token.span.close().end().line;
            self.record(&item.sig.ident, start, fn_line, end);
            syn::visit::visit_block(self, block);
        }
    }
}

/// The last path segment of an `impl`'s type (`Foo` of `impl<T> Trait for a::Foo<T>`).
fn quote_type(ty: &syn::Type) -> String {
    match ty {
        syn::Type::Path(p) => p
            .path
            .segments
            .last()
            .map(|s| s.ident.to_string())
            .unwrap_or_default(),
        syn::Type::Reference(r) => quote_type(&r.elem),
        _ => "_".into(),
    }
}

/// Prints the table and the counts; with `check`, fails when a long function has no reason or
/// there are more than `max_count`.
pub fn run(root: &Path, max_lines: usize, max_count: usize, check: bool) -> anyhow::Result<()> {
    let found = long_functions(root, max_lines)?;
    println!("| lines | function | where | why it stays |");
    println!("|---:|---|---|---|");
    for f in &found {
        println!(
            "| {} | `{}` | {}:{} | {} |",
            f.lines,
            f.name,
            f.file.display(),
            f.line,
            f.justification.as_deref().unwrap_or("–")
        );
    }
    let unjustified = found.iter().filter(|f| f.justification.is_none()).count();
    println!(
        "functions over {max_lines} lines in shipped code: {} ({unjustified} without a reason)",
        found.len()
    );
    if check {
        anyhow::ensure!(
            found.len() <= max_count,
            "{} functions over {max_lines} lines; at most {max_count}",
            found.len()
        );
        anyhow::ensure!(
            unjustified == 0,
            "{unjustified} functions over {max_lines} lines without a `{JUSTIFICATION}` comment"
        );
    }
    Ok(())
}
