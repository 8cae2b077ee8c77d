//! docs/reference/cli.md documents the command line as `--help` prints it:
//! every subcommand (recursively) has a section headed `` `nvtmm a b` ``;
//! every option and argument of a command appears in its section; every
//! `--flag` the page names in a section exists on that command (or on one
//! of its subcommands, for a group's table); no section names a command
//! that does not exist. The README's command lines are checked the same way
//! (every `--flag` it shows exists on the command it follows).

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

const PAGE: &str = "docs/reference/cli.md";

fn help(path: &[String]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(path)
        .arg("--help")
        .output()
        .expect("nvtmm runs");
    assert!(out.status.success(), "nvtmm {} --help failed", path.join(" "));
    String::from_utf8(out.stdout).unwrap()
}

/// The entries of a `Commands:`, `Arguments:` or `Options:` block.
fn block<'a>(text: &'a str, title: &str) -> Vec<&'a str> {
    let mut on = false;
    let mut out = Vec::new();
    for l in text.lines() {
        if l == format!("{title}:") {
            on = true;
        } else if on && !l.is_empty() && !l.starts_with(' ') {
            on = false;
        } else if on {
            let t = l.trim_start();
            // An entry starts two spaces in (long help indents its text more).
            if l.len() - t.len() <= 6 && !t.is_empty() {
                out.push(t);
            }
        }
    }
    out
}

/// What one command accepts.
#[derive(Debug, Default)]
struct Cmd {
    flags: Vec<String>,
    args: Vec<String>,
    subs: Vec<String>,
    /// Every `--flag` its help text mentions (its own, and others' it
    /// refers to, e.g. `run --record` in `replay`'s).
    quoted: Vec<String>,
}

fn walk(path: Vec<String>, out: &mut BTreeMap<Vec<String>, Cmd>) {
    let text = help(&path);
    let mut c = Cmd::default();
    for e in block(&text, "Options") {
        // The option's spec, before its description (two spaces on).
        let spec = e.split("  ").next().unwrap_or(e);
        for tok in spec.split([' ', ',']) {
            if tok.starts_with("--") && tok != "--help" && tok != "--version" {
                c.flags.push(tok.to_string());
            }
        }
    }
    for e in block(&text, "Arguments") {
        c.args.push(e.split_whitespace().next().unwrap().to_string());
    }
    for e in block(&text, "Commands") {
        let name = e.split_whitespace().next().unwrap();
        if name != "help" && e.starts_with(|ch: char| ch.is_ascii_lowercase()) {
            c.subs.push(name.to_string());
        }
    }
    c.quoted = flags_in(&text);
    let subs = c.subs.clone();
    out.insert(path.clone(), c);
    for s in subs {
        let mut p = path.clone();
        p.push(s);
        walk(p, out);
    }
}

/// `--flag` tokens in `text`.
fn flags_in(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let b = text.as_bytes();
    let mut i = 0;
    while let Some(k) = text[i..].find("--") {
        let s = i + k;
        let before_ok = s == 0 || !(b[s - 1].is_ascii_alphanumeric() || b[s - 1] == b'-');
        let mut e = s + 2;
        while e < b.len() && (b[e].is_ascii_lowercase() || b[e].is_ascii_digit() || b[e] == b'-') {
            e += 1;
        }
        if before_ok && e > s + 2 && b[s + 2].is_ascii_lowercase() {
            out.push(text[s..e].trim_end_matches('-').to_string());
        }
        i = e.max(s + 2);
    }
    out
}

/// The page's sections: command path → text.
fn sections(page: &str) -> BTreeMap<Vec<String>, String> {
    let mut out = BTreeMap::new();
    let mut cur: Option<Vec<String>> = None;
    for line in page.lines() {
        if line.starts_with('#') {
            let title = line.trim_start_matches('#').trim();
            cur = title
                .strip_prefix("`nvtmm")
                .and_then(|t| t.strip_suffix('`'))
                .map(|t| t.split_whitespace().map(str::to_string).collect());
            if let Some(p) = &cur {
                assert!(
                    out.insert(p.clone(), String::new()).is_none(),
                    "{PAGE}: two sections for {p:?}"
                );
            }
            continue;
        }
        if let Some(p) = &cur {
            let s = out.get_mut(p).unwrap();
            s.push_str(line);
            s.push('\n');
        }
    }
    out
}

#[test]
fn cli_reference_matches_help() {
    let mut cmds = BTreeMap::new();
    walk(Vec::new(), &mut cmds);
    let page = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(PAGE)).unwrap();
    let secs = sections(&page);
    let mut defects = Vec::new();
    for (path, c) in &cmds {
        if path.is_empty() {
            continue;
        }
        let name = format!("nvtmm {}", path.join(" "));
        let Some(text) = secs.get(path) else {
            defects.push(format!("{PAGE}: no section for `{name}` (a heading ### `{name}`)"));
            continue;
        };
        let named = flags_in(text);
        for f in &c.flags {
            if !named.contains(f) {
                defects.push(format!("{PAGE}: `{name}`: option {f} is not documented"));
            }
        }
        for a in &c.args {
            if !text.contains(a.as_str()) {
                defects.push(format!("{PAGE}: `{name}`: argument {a} is not documented"));
            }
        }
        for s in &c.subs {
            if !text.contains(&format!("`{s}`")) {
                defects.push(format!("{PAGE}: `{name}`: subcommand `{s}` is not listed"));
            }
        }
        // Flags of this command or of its subcommands.
        let known: Vec<&String> = cmds
            .iter()
            .filter(|(p, _)| p.starts_with(path))
            .flat_map(|(_, c)| c.flags.iter().chain(&c.quoted))
            .collect();
        for f in named {
            if !known.contains(&&f) {
                defects.push(format!(
                    "{PAGE}: `{name}`: names {f}, which `{name} --help` does not have"
                ));
            }
        }
    }
    for path in secs.keys() {
        if !cmds.contains_key(path) {
            defects.push(format!(
                "{PAGE}: a section for `nvtmm {}`, which does not exist",
                path.join(" ")
            ));
        }
    }
    assert!(defects.is_empty(), "{} defects:\n{}", defects.len(), defects.join("\n"));
    println!(
        "{} commands, {} options checked",
        cmds.len() - 1,
        cmds.values().map(|c| c.flags.len()).sum::<usize>()
    );
}

/// Every `nvtmm …` command line in the README (code blocks) uses options
/// that command has.
#[test]
fn readme_command_lines_match_help() {
    let mut cmds = BTreeMap::new();
    walk(Vec::new(), &mut cmds);
    let readme = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md")).unwrap();
    let mut defects = Vec::new();
    let mut checked = 0;
    for line in readme.lines() {
        let Some(i) = line.find("nvtmm ") else { continue };
        let words: Vec<&str> = line[i..].split_whitespace().collect();
        // The longest command path the words start with.
        let mut path: Vec<String> = Vec::new();
        for w in &words[1..] {
            let mut p = path.clone();
            p.push(w.trim_matches('`').to_string());
            if cmds.contains_key(&p) {
                path = p;
            } else {
                break;
            }
        }
        if path.is_empty() {
            continue;
        }
        // Options up to the end of the command (a closing backtick, a pipe).
        let rest = &line[i..];
        let end = rest[1..]
            .find(['`', '|', '#', ';', ')'])
            .map(|e| e + 1)
            .unwrap_or(rest.len());
        let c = &cmds[&path];
        for f in flags_in(&rest[..end]) {
            checked += 1;
            if !c.flags.contains(&f) {
                defects.push(format!(
                    "README.md: `{}`: nvtmm {} has no {f}",
                    line.trim(),
                    path.join(" ")
                ));
            }
        }
    }
    assert!(defects.is_empty(), "{}", defects.join("\n"));
    println!("{checked} options in README command lines checked");
}
