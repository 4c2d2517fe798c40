//! The report as data: a list of [`Block`]s rendered twice, to HTML ([`to_html`]) and to
//! Markdown ([`to_markdown`]), so both files always say the same thing.

use std::fmt::Write as _;

/// One image of a figure row; `src` is relative to the report directory.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    /// The picture (PNG), relative to the report directory: what the Markdown page shows.
    pub src: String,
    pub caption: String,
    /// Draw a checkerboard behind the image (layers with transparent pixels).
    pub checker: bool,
    /// The same picture as SVG (plots), which the HTML page shows instead.
    pub vector: Option<String>,
}

/// A table with a stable `id` (the browser test looks tables up by it).
#[derive(Clone, Debug, PartialEq)]
pub struct Table {
    pub id: String,
    pub caption: String,
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

/// One piece of the report.
#[derive(Clone, Debug, PartialEq)]
pub enum Block {
    /// A section heading; `id` is the anchor.
    Section {
        id: String,
        title: String,
    },
    Para(String),
    /// The command that reproduces the numbers and images that follow.
    Command(String),
    /// A section (or part of one) whose inputs do not exist, and why.
    Unavailable(String),
    Table(Table),
    Figures(Vec<Figure>),
    /// Preformatted text (commands to run later).
    Code(String),
}

/// Escape text for HTML element content and attribute values.
pub fn escape_html(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            _ => out.push(c),
        }
    }
    out
}

/// A cell that holds a number (possibly with a unit sign), right-aligned in tables.
fn is_numeric(cell: &str) -> bool {
    let t = cell.trim().trim_end_matches('%');
    matches!(t, "∞" | "–") || (!t.is_empty() && t.parse::<f64>().is_ok())
}

/// Escape a table cell for Markdown (pipes and line breaks would break the row).
fn escape_md_cell(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', " ")
}

/// Percent-encode the characters of a relative link that HTML/Markdown would misread.
fn encode_src(src: &str) -> String {
    let mut out = String::with_capacity(src.len());
    for b in src.bytes() {
        match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'/' | b'~' => {
                out.push(b as char)
            }
            _ => {
                let _ = write!(out, "%{b:02X}");
            }
        }
    }
    out
}

const STYLE: &str = "\
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;max-width:76rem;margin:2rem auto;\
padding:0 1rem;color:#1d232a;line-height:1.45;background:#fbfbfa}\
h1{font-size:1.7rem;margin-bottom:.2rem}h2{margin-top:2.4rem;border-bottom:1px solid #d8dce0;\
padding-bottom:.25rem}nav a{margin-right:.8rem}\
table{border-collapse:collapse;margin:.8rem 0;font-size:.9rem;font-variant-numeric:tabular-nums}\
th,td{border:1px solid #ccd2d8;padding:.25rem .55rem;text-align:left}\
th{background:#eef1f4}td.n{text-align:right}\
caption{caption-side:top;text-align:left;font-weight:600;padding:.3rem 0}\
code,pre{font-family:ui-monospace,'DejaVu Sans Mono',monospace;font-size:.85rem}\
p.cmd{background:#eef3f8;border-left:3px solid #5b84b1;padding:.3rem .6rem;overflow-x:auto;\
white-space:nowrap}p.cmd::before{content:'reproduce: ';color:#5b6b7b}\
pre{background:#f1f1ee;padding:.6rem;overflow-x:auto}\
p.unavailable{background:#fff6e5;border-left:3px solid #d99a1e;padding:.4rem .6rem}\
div.figs{display:flex;flex-wrap:wrap;gap:1rem;align-items:flex-start}\
figure{margin:0;max-width:100%}figure img{max-width:100%;min-width:min(100%,24rem);height:auto;\
border:1px solid #ccd2d8;image-rendering:pixelated}figcaption{font-size:.85rem;color:#4a5560}\
img.checker{background:repeating-conic-gradient(#d0d0d0 0% 25%,#fff 0% 50%) 50%/16px 16px}\
img.plot{image-rendering:auto;width:45rem}";

/// The whole page.
pub fn to_html(title: &str, blocks: &[Block]) -> String {
    let mut h = String::new();
    h += "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n";
    h += "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n";
    let _ = writeln!(h, "<title>{}</title>", escape_html(title));
    let _ = writeln!(h, "<style>{STYLE}</style>\n</head>\n<body>");
    let _ = writeln!(h, "<h1>{}</h1>", escape_html(title));
    let sections: Vec<(&str, &str)> = blocks
        .iter()
        .filter_map(|b| match b {
            Block::Section { id, title } => Some((id.as_str(), title.as_str())),
            _ => None,
        })
        .collect();
    if !sections.is_empty() {
        h += "<nav>";
        for (id, t) in &sections {
            let _ = write!(h, "<a href=\"#{}\">{}</a>", escape_html(id), escape_html(t));
        }
        h += "</nav>\n";
    }
    for b in blocks {
        match b {
            Block::Section { id, title } => {
                let _ = writeln!(
                    h,
                    "<h2 id=\"{}\">{}</h2>",
                    escape_html(id),
                    escape_html(title)
                );
            }
            Block::Para(t) => {
                let _ = writeln!(h, "<p>{}</p>", escape_html(t));
            }
            Block::Command(c) => {
                let _ = writeln!(h, "<p class=\"cmd\"><code>{}</code></p>", escape_html(c));
            }
            Block::Unavailable(t) => {
                let _ = writeln!(
                    h,
                    "<p class=\"unavailable\">Not available: {}</p>",
                    escape_html(t)
                );
            }
            Block::Code(t) => {
                let _ = writeln!(h, "<pre>{}</pre>", escape_html(t));
            }
            Block::Table(t) => {
                let _ = writeln!(h, "<table id=\"{}\">", escape_html(&t.id));
                let _ = writeln!(h, "<caption>{}</caption>", escape_html(&t.caption));
                h += "<thead><tr>";
                for c in &t.header {
                    let _ = write!(h, "<th>{}</th>", escape_html(c));
                }
                h += "</tr></thead>\n<tbody>\n";
                for row in &t.rows {
                    h += "<tr>";
                    for c in row {
                        let class = if is_numeric(c) { " class=\"n\"" } else { "" };
                        let _ = write!(h, "<td{class}>{}</td>", escape_html(c));
                    }
                    h += "</tr>\n";
                }
                h += "</tbody>\n</table>\n";
            }
            Block::Figures(figs) => {
                h += "<div class=\"figs\">\n";
                for f in figs {
                    let class = if f.vector.is_some() {
                        " class=\"plot\""
                    } else if f.checker {
                        " class=\"checker\""
                    } else {
                        ""
                    };
                    let _ = writeln!(
                        h,
                        "<figure><img{class} src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
                        escape_html(&encode_src(f.vector.as_deref().unwrap_or(&f.src))),
                        escape_html(&f.caption),
                        escape_html(&f.caption)
                    );
                }
                h += "</div>\n";
            }
        }
    }
    h += "</body>\n</html>\n";
    h
}

/// The same page as Markdown (GitHub flavour: pipe tables, relative image links).
pub fn to_markdown(title: &str, blocks: &[Block]) -> String {
    let mut m = format!("# {title}\n");
    for b in blocks {
        m.push('\n');
        match b {
            Block::Section { title, .. } => {
                let _ = writeln!(m, "## {title}");
            }
            Block::Para(t) => {
                let _ = writeln!(m, "{t}");
            }
            Block::Command(c) => {
                let _ = writeln!(m, "Reproduce: `{c}`");
            }
            Block::Unavailable(t) => {
                let _ = writeln!(m, "> **Not available:** {}", t.replace('\n', " "));
            }
            Block::Code(t) => {
                let _ = writeln!(m, "```sh\n{}\n```", t.trim_end());
            }
            Block::Table(t) => {
                let _ = writeln!(m, "**{}**\n", t.caption);
                let row = |cells: &[String]| {
                    let cells: Vec<String> = cells.iter().map(|c| escape_md_cell(c)).collect();
                    format!("| {} |\n", cells.join(" | "))
                };
                m += &row(&t.header);
                let rule: Vec<String> = (0..t.header.len())
                    .map(|i| if i == 0 { "---" } else { "---:" }.to_string())
                    .collect();
                let _ = writeln!(m, "|{}|", rule.join("|"));
                for r in &t.rows {
                    m += &row(r);
                }
            }
            Block::Figures(figs) => {
                for f in figs {
                    let _ = writeln!(m, "![{}]({})", f.caption, encode_src(&f.src));
                }
            }
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<Block> {
        vec![
            Block::Section {
                id: "culling".into(),
                title: "Culling <α>".into(),
            },
            Block::Command("railview cull work --alpha 1.0".into()),
            Block::Table(Table {
                id: "t1".into(),
                caption: "Tiles & bytes".into(),
                header: vec!["a|b".into(), "c".into()],
                rows: vec![vec!["1".into(), "<2>".into()]],
            }),
            Block::Figures(vec![
                Figure {
                    src: "view 1.png".into(),
                    caption: "a \"view\"".into(),
                    checker: true,
                    vector: None,
                },
                Figure {
                    src: "plot.png".into(),
                    caption: "a plot".into(),
                    checker: false,
                    vector: Some("plot.svg".into()),
                },
            ]),
            Block::Unavailable("`cull` is missing".into()),
        ]
    }

    #[test]
    fn html_escapes_text_and_links() {
        let h = to_html("R & D", &sample());
        assert!(h.contains("<title>R &amp; D</title>"));
        assert!(h.contains("<h2 id=\"culling\">Culling &lt;α&gt;</h2>"));
        assert!(h.contains("<table id=\"t1\">"));
        assert!(h.contains("<td>&lt;2&gt;</td>"));
        assert!(h.contains("<td class=\"n\">1</td>"));
        assert!(h.contains("src=\"view%201.png\""));
        assert!(h.contains("alt=\"a &quot;view&quot;\""));
        assert!(h.contains("class=\"checker\""));
        // A plot: the SVG in the page, the PNG in the Markdown.
        assert!(h.contains("<img class=\"plot\" src=\"plot.svg\""));
        assert!(to_markdown("R", &sample()).contains("(plot.png)"));
        assert!(h.contains("<a href=\"#culling\">"));
        assert!(!h.contains("http://") && !h.contains("https://"));
    }

    #[test]
    fn markdown_has_tables_images_and_escaped_cells() {
        let m = to_markdown("R", &sample());
        assert!(m.contains("| a\\|b | c |\n|---|---:|\n| 1 | <2> |"));
        assert!(m.contains("![a \"view\"](view%201.png)"));
        assert!(m.contains("Reproduce: `railview cull work --alpha 1.0`"));
        assert!(m.contains("> **Not available:** `cull` is missing"));
    }

    #[test]
    fn non_ascii_links_are_percent_encoded() {
        assert_eq!(encode_src("é/x y.png"), "%C3%A9/x%20y.png");
    }
}
