//! The documentation stands alone: every relative link in every Markdown
//! file of the repository and in every doc comment of the Rust sources
//! resolves to a file or directory inside the repository, and no file cites
//! notes that live outside it.

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Files under `dir` with one of `exts`, skipping build output and VCS data.
fn walk(dir: &Path, exts: &[&str], out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let p = e.path();
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if p.is_dir() {
            if !matches!(name, "target" | ".git" | "node_modules" | "fixtures") && !name.starts_with('.') {
                walk(&p, exts, out);
            }
        } else if exts.iter().any(|x| name.ends_with(x)) {
            out.push(p);
        }
    }
}

/// The targets of `](target)` links in `text` that are relative paths.
fn relative_links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("](") {
        rest = &rest[i + 2..];
        let end = rest.find([')', ' ', '\n']).unwrap_or(rest.len());
        let target = &rest[..end];
        let path = target.split('#').next().unwrap_or("");
        let external = ["http://", "https://", "mailto:"].iter().any(|s| target.starts_with(s));
        // Rustdoc intra-doc links (`[x](crate::y)`, `(mod@z)`) are checked by rustdoc.
        let intra = path.contains("::") || path.contains('@') || path.starts_with("crate");
        if !path.is_empty() && !external && !intra {
            out.push(path.to_string());
        }
    }
    out
}

#[test]
fn every_relative_link_in_markdown_and_doc_comments_resolves_inside_the_repository() {
    let root = root();
    let mut files = Vec::new();
    walk(&root, &[".md"], &mut files);
    let mut sources = Vec::new();
    walk(&root.join("src"), &[".rs"], &mut sources);
    walk(&root.join("capi"), &[".rs"], &mut sources);
    let mut broken = Vec::new();
    let mut checked = 0;
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        for l in relative_links(&text) {
            checked += 1;
            let target = f.parent().unwrap().join(&l);
            if !target.exists() {
                broken.push(format!("{}: {l}", f.strip_prefix(&root).unwrap().display()));
            }
        }
    }
    for f in &sources {
        let text = std::fs::read_to_string(f).unwrap();
        let docs: String = text
            .lines()
            .map(str::trim_start)
            .filter(|l| l.starts_with("//!") || l.starts_with("///"))
            .collect::<Vec<_>>()
            .join("\n");
        for l in relative_links(&docs) {
            checked += 1;
            // Doc comments link relative to the repository root or the file.
            if !root.join(&l).exists() && !f.parent().unwrap().join(&l).exists() {
                broken.push(format!("{}: {l}", f.strip_prefix(&root).unwrap().display()));
            }
        }
        // Plain mentions of docs/*.md in doc comments must exist too.
        for (i, _) in docs.match_indices("docs/") {
            let tail = &docs[i..];
            let end = tail
                .find(|c: char| !(c.is_ascii_alphanumeric() || "/._-".contains(c)))
                .unwrap_or(tail.len());
            let mention = tail[..end].trim_end_matches('.');
            if mention.ends_with(".md") {
                checked += 1;
                if !root.join(mention).exists() {
                    broken.push(format!("{}: {mention}", f.strip_prefix(&root).unwrap().display()));
                }
            }
        }
    }
    eprintln!(
        "{checked} links checked in {} Markdown and {} Rust files",
        files.len(),
        sources.len()
    );
    assert!(checked > 50, "the scan found the links ({checked})");
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn no_file_cites_notes_outside_the_repository() {
    let root = root();
    let mut files = Vec::new();
    walk(&root, &[".md", ".rs", ".toml", ".py", ".sh", ".h", ".c"], &mut files);
    let needles = ["shared/DESIGN", "shared/STYLE", "shared/reference", "shared/paper"];
    let mut bad = Vec::new();
    for f in &files {
        if f.ends_with("docs_links_resolve.rs") {
            continue;
        }
        let text = std::fs::read_to_string(f).unwrap_or_default();
        for n in needles {
            if text.contains(n) {
                bad.push(format!("{}: {n}", f.strip_prefix(&root).unwrap().display()));
            }
        }
    }
    assert!(bad.is_empty(), "cites notes users do not have:\n{}", bad.join("\n"));
}
