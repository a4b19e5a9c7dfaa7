//! Small pieces of a self-contained HTML page: escaping, tables, images inlined as data URIs.

use std::fmt::Write as _;
use std::path::Path;

use base64::Engine as _;

/// Text escaped for HTML content and attribute values.
pub fn esc(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for ch in text.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// `data:<mime>;base64,…` for bytes, so the page needs no other file.
pub fn data_uri(mime: &str, bytes: &[u8]) -> String {
    format!(
        "data:{mime};base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

/// A PNG file as a data URI, `None` when it is missing or unreadable.
pub fn png_file_uri(path: &Path) -> Option<String> {
    let bytes = std::fs::read(path).ok()?;
    bytes
        .starts_with(b"\x89PNG")
        .then(|| data_uri("image/png", &bytes))
}

/// An `<img>` of a data URI with alternative text, or a note saying what is missing.
pub fn img(uri: Option<&str>, alt: &str, class: &str) -> String {
    match uri {
        Some(uri) => format!("<img class=\"{class}\" src=\"{uri}\" alt=\"{}\">", esc(alt)),
        None => format!("<p class=\"missing\">{} not available.</p>", esc(alt)),
    }
}

/// One figure of a [`figure_row`]: image (data URI, when present), alternative text, CSS
/// class, caption.
pub type Figure<'a> = (Option<&'a str>, &'a str, &'a str, &'a str);

/// Images side by side, each with its caption.
pub fn figure_row(figures: &[Figure<'_>]) -> String {
    let mut out = String::from("<div class=\"row\">");
    for (uri, alt, class, caption) in figures {
        let _ = write!(
            out,
            "<figure>{}<figcaption>{}</figcaption></figure>",
            img(*uri, alt, class),
            esc(caption)
        );
    }
    out.push_str("</div>");
    out
}

/// A table of already escaped (or numeric) cells; the first column is a row header.
pub fn table(headers: &[&str], rows: &[Vec<String>]) -> String {
    let mut out = String::from("<table><thead><tr>");
    for h in headers {
        let _ = write!(out, "<th>{}</th>", esc(h));
    }
    out.push_str("</tr></thead><tbody>");
    for row in rows {
        out.push_str("<tr>");
        for (i, cell) in row.iter().enumerate() {
            let tag = if i == 0 { "th" } else { "td" };
            let _ = write!(out, "<{tag}>{cell}</{tag}>");
        }
        out.push_str("</tr>");
    }
    out.push_str("</tbody></table>");
    out
}

/// A number with `digits` decimals, or an en dash for none / not finite.
pub fn num(value: Option<f64>, digits: usize) -> String {
    match value {
        Some(v) if v.is_finite() => format!("{v:.digits$}"),
        _ => "–".into(),
    }
}

/// A number in millimetres from metres.
pub fn mm(value: Option<f64>, digits: usize) -> String {
    num(value.map(|v| v * 1000.0), digits)
}

/// The page's style: readable on screen and printable, no external font.
pub const STYLE: &str = "
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:0 auto;max-width:1180px;padding:0 18px 40px;color:#1d2327;line-height:1.4}
h1{margin:18px 0 4px} h2{border-bottom:2px solid #2c6e91;padding-bottom:3px;margin-top:34px} h3{margin:22px 0 6px}
nav a{margin-right:14px} .meta{color:#555}
table{border-collapse:collapse;margin:8px 0 14px;font-size:14px} th,td{border:1px solid #c8d0d5;padding:3px 8px;text-align:right}
thead th{background:#e8eef2} tbody th{text-align:left;font-weight:600;background:#f6f8f9}
.row{display:flex;flex-wrap:wrap;gap:16px;align-items:flex-start} .row figure{margin:0;flex:1 1 340px;max-width:560px}
figure img,figure svg{width:100%;height:auto;border:1px solid #d0d7dc;background:#fff} figcaption{font-size:13px;color:#444}
.warn{background:#fff4e0;border-left:4px solid #e08a00;padding:6px 10px;margin:6px 0}
.ok{background:#e9f6ec;border-left:4px solid #2f8f46;padding:6px 10px;margin:6px 0}
.missing{color:#888;font-style:italic} pre{background:#f4f6f7;padding:8px;overflow:auto;font-size:12px}
.legend span{display:inline-block;padding:1px 7px;margin-right:3px;font-size:12px;border:1px solid #999}
td.heat{color:#000}
";
