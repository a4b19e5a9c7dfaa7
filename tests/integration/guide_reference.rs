//! The guide's reference pages are generated, never written by hand, and a test fails when the
//! committed page is stale:
//! - `docs/guide/src/reference/project-toml.md`: every `project.toml` key with its type, its
//!   default and its meaning, read from the config types' doc comments (`src/config.rs`, and the
//!   strategy names of `timesift-align`) and from the defaults a project without the key gets;
//! - `docs/guide/src/reference/cli.md`: every command's `--help`, as clap prints it.
//!
//! `cargo xtask guide --bless` (or `TIMESIFT_BLESS=1` on this test) writes them.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use syn::{Attribute, Fields, Item, Type};
use timesift::config::ProjectConfig;

const CONFIG_SOURCES: [&str; 2] = ["src/config.rs", "crates/align/src/strategy/method.rs"];
const TOML_PAGE: &str = "docs/guide/src/reference/project-toml.md";
const CLI_PAGE: &str = "docs/guide/src/reference/cli.md";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A struct's or a field's doc comment, as Markdown paragraphs.
fn doc_of(attrs: &[Attribute]) -> String {
    let mut lines = Vec::new();
    for attr in attrs {
        if !attr.path().is_ident("doc") {
            continue;
        }
        if let syn::Meta::NameValue(nv) = &attr.meta
            && let syn::Expr::Lit(syn::ExprLit {
                lit: syn::Lit::Str(s),
                ..
            }) = &nv.value
        {
            lines.push(s.value().trim().to_string());
        }
    }
    // Lines of one paragraph joined by spaces, paragraphs by a blank line.
    let mut text = String::new();
    for line in lines {
        if line.is_empty() {
            text.push_str("\n\n");
        } else {
            if !(text.is_empty() || text.ends_with('\n')) {
                text.push(' ');
            }
            text.push_str(&line);
        }
    }
    text.trim().to_string()
}

/// The `#[serde(...)]` words of an item or field: `default`, `rename = "..."`, `untagged`, ...
#[derive(Default)]
struct Serde {
    default: bool,
    rename: Option<String>,
    rename_all: Option<String>,
    /// `untagged`, or `try_from`: the forms are the variants' payloads.
    by_form: bool,
}

fn serde_of(attrs: &[Attribute]) -> Serde {
    let mut serde = Serde::default();
    for attr in attrs.iter().filter(|a| a.path().is_ident("serde")) {
        attr.parse_nested_meta(|meta| {
            let value = if meta.input.peek(syn::Token![=]) {
                Some(meta.value()?.parse::<syn::LitStr>()?.value())
            } else {
                None
            };
            let name = meta
                .path
                .get_ident()
                .map(|i| i.to_string())
                .unwrap_or_default();
            match name.as_str() {
                "default" => serde.default = true,
                "rename" => serde.rename = value,
                "rename_all" => serde.rename_all = value,
                "untagged" | "try_from" => serde.by_form = true,
                _ => {}
            }
            Ok(())
        })
        .expect("a #[serde(...)] attribute of the config types");
    }
    serde
}

struct Field {
    key: String,
    doc: String,
    ty: Type,
    required: bool,
}

struct Struct {
    doc: String,
    fields: Vec<Field>,
}

struct Variant {
    /// The TOML spelling of a unit variant; `None` for a variant with a payload.
    name: Option<String>,
    payload: Option<Type>,
    doc: String,
}

struct Enum {
    by_form: bool,
    variants: Vec<Variant>,
}

/// The config types, by Rust name, as the sources declare them.
struct Types {
    structs: BTreeMap<String, Struct>,
    enums: BTreeMap<String, Enum>,
}

fn kebab(ident: &str) -> String {
    let mut out = String::new();
    for (i, c) in ident.chars().enumerate() {
        if c.is_uppercase() && i > 0 {
            out.push('-');
        }
        out.extend(c.to_lowercase());
    }
    out
}

fn read_types() -> Types {
    let mut types = Types {
        structs: BTreeMap::new(),
        enums: BTreeMap::new(),
    };
    for source in CONFIG_SOURCES {
        let text = std::fs::read_to_string(root().join(source)).expect(source);
        let file = syn::parse_file(&text).expect(source);
        for item in file.items {
            match item {
                Item::Struct(s) => {
                    let Fields::Named(named) = &s.fields else {
                        continue;
                    };
                    let fields = named
                        .named
                        .iter()
                        .map(|f| {
                            let serde = serde_of(&f.attrs);
                            let ident = f.ident.as_ref().expect("a named field").to_string();
                            let optional = type_name(&f.ty).0 == "Option";
                            Field {
                                key: serde.rename.unwrap_or(ident),
                                doc: doc_of(&f.attrs),
                                ty: f.ty.clone(),
                                required: !serde.default && !optional,
                            }
                        })
                        .collect();
                    let doc = doc_of(&s.attrs);
                    types
                        .structs
                        .insert(s.ident.to_string(), Struct { doc, fields });
                }
                Item::Enum(e) => {
                    let serde = serde_of(&e.attrs);
                    let variants = e
                        .variants
                        .iter()
                        .map(|v| {
                            let ident = v.ident.to_string();
                            let payload = match &v.fields {
                                Fields::Unnamed(u) => u.unnamed.first().map(|f| f.ty.clone()),
                                _ => None,
                            };
                            let name = payload.is_none().then(|| {
                                match (serde_of(&v.attrs).rename, serde.rename_all.as_deref()) {
                                    (Some(name), _) => name,
                                    (None, Some("kebab-case")) => kebab(&ident),
                                    // lowercase, and the strategies' own names (Method::name).
                                    (None, _) => ident.to_lowercase(),
                                }
                            });
                            Variant {
                                name,
                                payload,
                                doc: doc_of(&v.attrs),
                            }
                        })
                        .collect();
                    let by_form = serde.by_form;
                    types
                        .enums
                        .insert(e.ident.to_string(), Enum { by_form, variants });
                }
                _ => {}
            }
        }
    }
    types
}

/// A type's last path segment and its generic arguments.
fn type_name(ty: &Type) -> (String, Vec<Type>) {
    if let Type::Path(p) = ty
        && let Some(last) = p.path.segments.last()
    {
        let args = match &last.arguments {
            syn::PathArguments::AngleBracketed(a) => a
                .args
                .iter()
                .filter_map(|g| match g {
                    syn::GenericArgument::Type(t) => Some(t.clone()),
                    _ => None,
                })
                .collect(),
            _ => Vec::new(),
        };
        return (last.ident.to_string(), args);
    }
    (String::new(), Vec::new())
}

/// How a value of the type is written in TOML.
fn describe(ty: &Type, types: &Types) -> String {
    if let Type::Array(a) = ty {
        let syn::Expr::Lit(syn::ExprLit {
            lit: syn::Lit::Int(n),
            ..
        }) = &a.len
        else {
            panic!("an array length that is not a number");
        };
        let n: usize = n.base10_parse().expect("array length");
        let one = describe(&a.elem, types);
        return format!("[{}]", vec![one; n].join(", "));
    }
    let (name, args) = type_name(ty);
    match name.as_str() {
        "String" => "string".into(),
        "PathBuf" => "path (string)".into(),
        "bool" => "boolean".into(),
        "f32" | "f64" => "number".into(),
        "usize" | "u32" | "u64" => "integer".into(),
        "Option" => describe(&args[0], types),
        "Vec" => format!("array of {}", describe(&args[0], types)),
        "BTreeMap" => format!("table of name = {}", describe(&args[1], types)),
        other => match types.enums.get(other) {
            Some(e) => e
                .variants
                .iter()
                .map(|v| match (&v.name, &v.payload) {
                    (_, Some(t)) if e.by_form => describe(t, types),
                    (Some(name), _) => format!("\"{name}\""),
                    _ => panic!("{other}: a variant with a payload in a unit enum"),
                })
                .collect::<Vec<_>>()
                .join(" or "),
            None => panic!("{other}: a config type this page cannot describe"),
        },
    }
}

/// The default a project gets without the key, as TOML.
fn default_of(field: &Field, defaults: Option<&toml::Value>) -> String {
    if field.required {
        return "required".into();
    }
    match defaults.and_then(|table| table.get(&field.key)) {
        Some(value) => format!("`{value}`"),
        None => "not set".into(),
    }
}

/// The page for `project.toml`.
fn toml_page(types: &Types) -> String {
    let config: ProjectConfig =
        toml::from_str("[[epoch]]\nname = \"e\"\n[[camera]]\nname = \"c\"\n")
            .expect("a minimal project.toml");
    let defaults = toml::Value::try_from(&config).expect("the defaults as TOML");
    let mut page = String::from(
        "<!-- Generated from the doc comments of src/config.rs by `cargo xtask guide --bless`: \
         edit those, not this page. -->\n\n# `project.toml`\n\n",
    );
    let root_type = &types.structs["ProjectConfig"];
    page.push_str(
        "A project's settings: its epochs, where its inputs are, and the options of each \
         stage. Every key is optional unless it says *required*; a key the file does not know is \
         an error that names it. `timesift init` writes a `project.toml` with every section \
         and its defaults. Types are TOML's: a string in quotes, a number, a boolean, an array \
         in brackets.\n\n",
    );
    // Keys of the root that are values, then each section in the file's order.
    let mut top = Vec::new();
    let mut sections = Vec::new();
    for field in &root_type.fields {
        let (name, args) = type_name(&field.ty);
        let inner = if name == "Vec" {
            type_name(&args[0]).0
        } else {
            name.clone()
        };
        match types.structs.get(&inner) {
            Some(s) => sections.push((field, name == "Vec", s)),
            None => top.push(field),
        }
    }
    page.push_str("## Top level\n\n");
    for field in top {
        key_entry(&mut page, None, field, Some(&defaults), types);
    }
    for (field, array, section) in sections {
        let header = if array {
            format!("[[{}]]", field.key)
        } else {
            format!("[{}]", field.key)
        };
        page.push_str(&format!("## `{header}`\n\n{}\n\n", field.doc));
        let bare = section.doc.trim_end_matches('.');
        let names_only_itself = bare.trim_start_matches("One ") == format!("`{header}`");
        if !section.doc.is_empty() && section.doc != field.doc && !names_only_itself {
            page.push_str(&format!("{}\n\n", section.doc));
        }
        let table = defaults.get(&field.key).map(|v| match v {
            toml::Value::Array(items) => items[0].clone(),
            other => other.clone(),
        });
        for key in &section.fields {
            key_entry(&mut page, Some(&header), key, table.as_ref(), types);
        }
    }
    page.trim_end().to_string() + "\n"
}

fn key_entry(
    page: &mut String,
    section: Option<&str>,
    field: &Field,
    defaults: Option<&toml::Value>,
    types: &Types,
) {
    let title = match section {
        Some(header) => format!("{header} {}", field.key),
        None => field.key.clone(),
    };
    page.push_str(&format!(
        "### `{title}`\n\n*{}* · default: {}\n\n{}\n\n",
        describe(&field.ty, types),
        default_of(field, defaults),
        field.doc
    ));
    // An enum's values with what each means.
    let (mut name, mut args) = type_name(&field.ty);
    while (name == "Option" || name == "Vec") && !args.is_empty() {
        (name, args) = type_name(&args[0]);
    }
    if let Some(e) = types.enums.get(&name) {
        for v in &e.variants {
            let form = match (&v.name, &v.payload) {
                (_, Some(t)) => describe(t, types),
                (Some(n), None) => format!("\"{n}\""),
                (None, None) => unreachable!("a variant has a name or a payload"),
            };
            page.push_str(&format!("- `{form}`: {}\n", v.doc));
        }
        page.push('\n');
    }
}

/// Every field and every value of the config types says what it is.
fn undocumented(types: &Types) -> Vec<String> {
    let mut missing = Vec::new();
    for (name, s) in &types.structs {
        for f in &s.fields {
            if f.doc.is_empty() {
                missing.push(format!("{name}.{}", f.key));
            }
        }
    }
    for (name, e) in &types.enums {
        for v in &e.variants {
            if v.doc.is_empty() {
                missing.push(format!(
                    "{name}::{}",
                    v.name.as_deref().unwrap_or("(payload)")
                ));
            }
        }
    }
    missing
}

fn help_of(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args(args)
        .arg("--help")
        .env("NO_COLOR", "1")
        .output()
        .expect("timesift runs");
    assert!(out.status.success(), "timesift {args:?} --help failed");
    String::from_utf8(out.stdout).expect("UTF-8 help")
}

/// The page of every command's `--help`.
fn cli_page() -> String {
    let top = help_of(&[]);
    let mut page = String::from(
        "<!-- Generated from the command line's own --help by `cargo xtask guide --bless`: \
         edit the clap doc comments in src/main.rs, not this page. -->\n\n# Command line\n\n",
    );
    page.push_str(&format!(
        "```text\n$ timesift --help\n{}\n```\n\n",
        top.trim_end()
    ));
    let commands: Vec<&str> = top
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .collect();
    assert!(
        commands.len() >= 10,
        "commands read from --help: {commands:?}"
    );
    for command in commands {
        page.push_str(&format!(
            "## `timesift {command}`\n\n```text\n$ timesift {command} --help\n{}\n```\n\n",
            help_of(&[command]).trim_end()
        ));
    }
    page.trim_end().to_string() + "\n"
}

/// Compares a generated page with the committed one, or writes it when blessing.
fn check_page(relative: &str, generated: &str) {
    let path = root().join(relative);
    if std::env::var_os("TIMESIFT_BLESS").is_some() {
        std::fs::create_dir_all(path.parent().expect("a folder")).expect("docs/guide");
        std::fs::write(&path, generated).expect("the page written");
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    if committed != generated {
        let line = committed
            .lines()
            .zip(generated.lines())
            .position(|(a, b)| a != b)
            .unwrap_or(committed.lines().count().min(generated.lines().count()));
        panic!(
            "{relative} is stale from line {} on (committed: {:?}, generated: {:?}): run \
             `cargo xtask guide --bless` and commit the page",
            line + 1,
            committed.lines().nth(line).unwrap_or("<end>"),
            generated.lines().nth(line).unwrap_or("<end>")
        );
    }
}

#[test]
fn the_project_toml_reference_is_generated_from_the_doc_comments_and_current() {
    let types = read_types();
    let missing = undocumented(&types);
    assert!(
        missing.is_empty(),
        "keys or values without a doc comment (the reference page is made from them): {missing:?}"
    );
    let page = toml_page(&types);
    // Every section and key the parser knows is on the page.
    for key in [
        "[align] method",
        "[dense] level",
        "[[camera]] distortion_um",
        "crs",
    ] {
        assert!(page.contains(&format!("### `{key}`")), "{key} missing");
    }
    assert!(page.contains("default: `\"timesift\"`"), "method's default");
    check_page(TOML_PAGE, &page);
}

#[test]
fn the_command_line_reference_is_every_commands_help_and_current() {
    let page = cli_page();
    for command in ["init", "run", "compare", "export", "status"] {
        assert!(
            page.contains(&format!("## `timesift {command}`")),
            "{command}"
        );
    }
    check_page(CLI_PAGE, &page);
}

/// The generator itself: a doc comment's paragraphs survive, a changed doc changes the page.
#[test]
fn a_changed_doc_comment_changes_the_page() {
    let mut types = read_types();
    let before = toml_page(&types);
    let field = types
        .structs
        .get_mut("DenseConfig")
        .and_then(|s| s.fields.iter_mut().find(|f| f.key == "level"))
        .expect("[dense] level");
    field.doc.push_str(" Changed.");
    let after = toml_page(&types);
    assert_ne!(before, after);
    assert!(after.contains(" Changed."));
    let attrs: Vec<Attribute> = vec![
        syn::parse_quote!(#[doc = " One"]),
        syn::parse_quote!(#[doc = " two."]),
        syn::parse_quote!(#[doc = ""]),
        syn::parse_quote!(#[doc = " Three."]),
    ];
    assert_eq!(doc_of(&attrs), "One two.\n\nThree.");
}
