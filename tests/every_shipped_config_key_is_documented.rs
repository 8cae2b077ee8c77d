//! docs/reference/config.md documents every configuration key, and what it
//! says holds:
//!
//! - every key of every shipped TOML file (`rt-config/**/*.toml`,
//!   `examples/**/*.toml`) has a row in the page's section for its kind of
//!   file (arrays of tables such as `[[prony]]` by their dotted key,
//!   `prony.alpha`);
//! - every row names a key the schema accepts (the file parses with it set);
//! - a default written as a TOML literal is the value the code takes when
//!   the key is left out;
//! - a range written as an interval (`[lo, hi]`, `(lo, hi]`, `lo..=hi`) is
//!   the one `validate()` enforces: the bounds (or just inside an open one)
//!   pass, just outside is refused at that key;
//! - a list of choices (`"a"`, `"b"`) is accepted one by one.
//!
//! The grammar of a row (`| key | unit | default | range | meaning |`) is
//! at the top of the page.

use nvtmm::config::{parse_toml, ConfigError};
use nvtmm::haptics::touchx::TouchXParams;
use nvtmm::haptics::udp::UdpParams;
use nvtmm::scene::Scene;
use nvtmm::service::ServiceConfig;
use std::path::{Path, PathBuf};
use toml::{Table, Value};

const PAGE: &str = "docs/reference/config.md";

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The kinds of configuration file, each its own schema and page section.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Service,
    Scene,
    TouchX,
    Udp,
}

const KINDS: [Kind; 4] = [Kind::Service, Kind::Scene, Kind::TouchX, Kind::Udp];

impl Kind {
    /// The page's section heading (a `## ` line starting with this).
    fn heading(self) -> &'static str {
        match self {
            Kind::Service => "## Service configuration",
            Kind::Scene => "## Scene",
            Kind::TouchX => "## Simulated Touch X",
            Kind::Udp => "## UDP bridge",
        }
    }

    /// Deserializes only (no range checks): the parsed value's `Debug`.
    fn parse(self, text: &str) -> Result<String, ConfigError> {
        let p = Path::new("doc-check.toml");
        Ok(match self {
            Kind::Service => format!("{:?}", parse_toml::<ServiceConfig>(text, p)?),
            Kind::Scene => format!("{:?}", parse_toml::<Scene>(text, p)?),
            Kind::TouchX => format!("{:?}", parse_toml::<TouchXParams>(text, p)?),
            Kind::Udp => format!("{:?}", parse_toml::<UdpParams>(text, p)?),
        })
    }

    /// Deserializes and validates.
    fn check(self, text: &str) -> Result<(), ConfigError> {
        let p = Path::new("doc-check.toml");
        match self {
            Kind::Service => ServiceConfig::parse(text, p).map(drop),
            Kind::Scene => Scene::parse(text, p, Path::new(".")).map(drop),
            Kind::TouchX => TouchXParams::from_toml_str(text, p).map(drop),
            Kind::Udp => UdpParams::from_toml_str(text, p).map(drop),
        }
    }
}

/// Which schema a shipped file follows, from its top-level keys.
fn classify(t: &Table) -> Option<Kind> {
    if t.contains_key("scene") {
        Some(Kind::Service)
    } else if t.contains_key("model") && t.contains_key("mesh") {
        Some(Kind::Scene)
    } else if t.contains_key("bind") {
        Some(Kind::Udp)
    } else if t.contains_key("peak_force_n") && t.contains_key("workspace_m") {
        Some(Kind::TouchX)
    } else {
        None
    }
}

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            walk(&p, out);
        } else if p.extension().is_some_and(|x| x == "toml") {
            out.push(p);
        }
    }
}

/// The shipped configuration files with their kind and parsed table.
fn shipped() -> Vec<(PathBuf, Kind, Table)> {
    let mut files = Vec::new();
    walk(&root().join("rt-config"), &mut files);
    walk(&root().join("examples"), &mut files);
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let rel = p.strip_prefix(root()).unwrap_or(&p).to_path_buf();
            let text = std::fs::read_to_string(&p).unwrap();
            let t: Table = text
                .parse()
                .unwrap_or_else(|e| panic!("{}: not TOML: {e}", rel.display()));
            let kind = classify(&t).unwrap_or_else(|| {
                panic!(
                    "{}: cannot tell which schema this file follows (service, scene, \
                     touchx, udp): teach classify() in {} and document its keys in {PAGE}",
                    rel.display(),
                    file!()
                )
            });
            (rel, kind, t)
        })
        .collect()
}

/// Every dotted key of `t` (leaves; a table inside an array counts by the
/// array's key, so `[[prony]] alpha` is `prony.alpha`).
fn flatten(t: &Table, prefix: &str, out: &mut Vec<String>) {
    for (k, v) in t {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            Value::Table(sub) => flatten(sub, &key, out),
            Value::Array(items) if !items.is_empty() && items.iter().all(Value::is_table) => {
                for item in items {
                    if let Value::Table(sub) = item {
                        flatten(sub, &key, out);
                    }
                }
            }
            _ => out.push(key),
        }
    }
}

/// One documented key.
#[derive(Debug, Clone)]
struct Row {
    kind: Kind,
    line: usize,
    key: String,
    default: String,
    range: String,
    /// Sibling values the checks need (`<!-- with a.b = v; c = w -->` in
    /// the row, invisible when rendered): e.g. a larger `tank_max_j` so
    /// that `tank_min_j` can reach its upper bound.
    with: Vec<(String, Value)>,
}

fn cells(line: &str) -> Vec<String> {
    let inner = line.trim().trim_start_matches('|').trim_end_matches('|');
    // `\|` inside a cell is a literal bar.
    inner
        .replace("\\|", "\u{0}")
        .split('|')
        .map(|c| c.trim().replace('\u{0}', "|"))
        .collect()
}

/// The rows of every key table, with the section they are in.
fn rows(page: &str) -> Vec<Row> {
    let mut out = Vec::new();
    let mut kind = None;
    for (i, line) in page.lines().enumerate() {
        if line.starts_with("## ") {
            kind = KINDS.into_iter().find(|k| line.starts_with(k.heading()));
            continue;
        }
        let Some(kind) = kind else { continue };
        if !line.trim_start().starts_with("| `") {
            continue;
        }
        let (line, with) = match line.split_once("<!-- with ") {
            Some((a, b)) => {
                let (ctx, rest) = b
                    .split_once("-->")
                    .unwrap_or_else(|| panic!("{PAGE}:{}: unclosed <!--", i + 1));
                let with = ctx
                    .split(';')
                    .map(|a| {
                        let (k, v) = a
                            .split_once(" = ")
                            .unwrap_or_else(|| panic!("{PAGE}:{}: `{a}`: not `key = value`", i + 1));
                        let v =
                            literal(v.trim()).unwrap_or_else(|| panic!("{PAGE}:{}: `{v}`: not a TOML value", i + 1));
                        (k.trim().to_string(), v)
                    })
                    .collect();
                (format!("{a}{rest}"), with)
            }
            None => (line.to_string(), Vec::new()),
        };
        let c = cells(&line);
        assert!(
            c.len() >= 5,
            "{PAGE}:{}: a key row has five cells (key | unit | default | range | meaning)",
            i + 1
        );
        let key = c[0].trim_matches('`').to_string();
        assert!(
            !key.contains(['`', ' ', ',']),
            "{PAGE}:{}: one key per row, written `a.b.c`",
            i + 1
        );
        out.push(Row {
            kind,
            line: i + 1,
            key,
            default: c[2].clone(),
            range: c[3].clone(),
            with,
        });
    }
    out
}

/// The backticked spans of a cell.
fn ticks(cell: &str) -> Vec<String> {
    cell.split('`').skip(1).step_by(2).map(str::to_string).collect()
}

/// `path = value` assignments in a cell (the context a row needs, e.g.
/// `integrator.linear = { kind = "cg" }`).
fn assignments(cell: &str) -> Vec<(String, Value)> {
    ticks(cell)
        .into_iter()
        .filter_map(|s| {
            let (k, v) = s.split_once(" = ")?;
            let k = k.trim();
            if k.is_empty() || !k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '.') {
                return None;
            }
            Some((k.to_string(), literal(v)?))
        })
        .collect()
}

fn literal(s: &str) -> Option<Value> {
    let t: Table = format!("v = {s}").parse().ok()?;
    t.get("v").cloned()
}

/// The default: a backticked literal at the start of the cell.
fn default_of(cell: &str) -> Option<Value> {
    let s = cell.strip_prefix('`')?;
    let s = &s[..s.find('`')?];
    if s.contains(" = ") && !s.starts_with('{') {
        return None;
    }
    literal(s)
}

/// A value to try the key with: the default, else an example (`e.g. `v``).
fn sample_of(cell: &str) -> Option<Value> {
    default_of(cell).or_else(|| {
        let i = cell.find("e.g. `")?;
        let s = &cell[i + 6..];
        literal(&s[..s.find('`')?])
    })
}

/// Sets `key` (dotted) in `t` to `v`, creating what is missing on the way
/// (a documented parent with a sample value, else a table holding its
/// documented required children's samples); inside an array of tables,
/// the first element.
fn set(t: &mut Table, key: &str, v: Value, doc: &[Row], kind: Kind) {
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = t;
    for (i, p) in parts.iter().enumerate() {
        if i == parts.len() - 1 {
            cur.insert(p.to_string(), v);
            return;
        }
        let path = parts[..=i].join(".");
        if !cur.contains_key(*p) {
            cur.insert(p.to_string(), fresh(&path, doc, kind));
        }
        cur = match cur.get_mut(*p) {
            Some(Value::Table(sub)) => sub,
            Some(Value::Array(items)) => match items.first_mut() {
                Some(Value::Table(sub)) => sub,
                _ => panic!("{key}: {path} is not a table"),
            },
            _ => panic!("{key}: {path} is not a table"),
        };
    }
}

/// A new value for the missing table `path`.
fn fresh(path: &str, doc: &[Row], kind: Kind) -> Value {
    let sample = doc
        .iter()
        .find(|r| r.kind == kind && r.key == path)
        .and_then(|r| sample_of(&r.default));
    match sample {
        // An empty array of tables: one table of its required keys.
        Some(Value::Array(a)) if a.is_empty() => return Value::Array(vec![required(path, doc, kind)]),
        Some(v) => return v,
        None => {}
    }
    required(path, doc, kind)
}

/// A table holding the samples of the documented required keys below `path`.
fn required(path: &str, doc: &[Row], kind: Kind) -> Value {
    let mut t = Table::new();
    for r in doc.iter().filter(|r| r.kind == kind && r.default.starts_with('—')) {
        if let Some(child) = r.key.strip_prefix(&format!("{path}.")) {
            if !child.contains('.') {
                if let Some(v) = sample_of(&r.default) {
                    t.insert(child.to_string(), v);
                }
            }
        }
    }
    Value::Table(t)
}

/// Removes `key` (dotted) from `t` if it is there.
fn remove(t: &mut Table, key: &str) {
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = t;
    for p in &parts[..parts.len() - 1] {
        cur = match cur.get_mut(*p) {
            Some(Value::Table(sub)) => sub,
            Some(Value::Array(items)) => match items.first_mut() {
                Some(Value::Table(sub)) => sub,
                _ => return,
            },
            _ => return,
        };
    }
    cur.remove(parts[parts.len() - 1]);
}

/// How many leading segments of `key` exist as tables in `t`.
fn depth(t: &Table, key: &str) -> usize {
    let mut cur = t;
    let mut n = 0;
    for p in key.split('.') {
        cur = match cur.get(p) {
            Some(Value::Table(sub)) => sub,
            Some(Value::Array(items)) => match items.first() {
                Some(Value::Table(sub)) => sub,
                _ => return n + 1,
            },
            Some(_) => return n + 1,
            None => return n,
        };
        n += 1;
    }
    n
}

/// The shipped file of `kind` that holds most of `key`'s path; among
/// those, the one with the fewest tables (the fewest other keys whose
/// checks a bound could trip), then the first by name.
fn base_for<'a>(files: &'a [(PathBuf, Kind, Table)], kind: Kind, key: &str) -> &'a (PathBuf, Kind, Table) {
    files
        .iter()
        .filter(|f| f.1 == kind)
        .max_by_key(|f| {
            (
                depth(&f.2, key),
                std::cmp::Reverse(f.2.len()),
                std::cmp::Reverse(f.0.clone()),
            )
        })
        .unwrap_or_else(|| panic!("no shipped file of kind {kind:?}"))
}

/// Whether `e` is about `key`: its key without indices is `key` or below
/// it, or it names a parent and its message names the rest of `key`.
fn about(e: &ConfigError, key: &str) -> bool {
    let mut k = String::new();
    let mut skip = false;
    for c in e.key.chars() {
        match c {
            '[' => skip = true,
            ']' => skip = false,
            _ if !skip => k.push(c),
            _ => {}
        }
    }
    if k == key || k.starts_with(&format!("{key}.")) {
        return true;
    }
    if let Some(rest) = key.strip_prefix(&format!("{k}.")) {
        let word = |c: char| c.is_ascii_alphanumeric() || c == '_';
        let tail = rest.rsplit('.').next().unwrap_or(rest);
        return e
            .msg
            .match_indices(rest)
            .chain(e.msg.match_indices(tail))
            .any(|(i, m)| {
                let before = e.msg[..i].chars().next_back().is_none_or(|c| !word(c));
                let after = e.msg[i + m.len()..].chars().next().is_none_or(|c| !word(c));
                before && after
            });
    }
    false
}

/// A value like `like` (a number, or an array of numbers) set to `x`.
fn like(like: &Value, x: f64, int: bool) -> Value {
    let num = |x: f64| if int { Value::Integer(x as i64) } else { Value::Float(x) };
    match like {
        Value::Array(items) => Value::Array(items.iter().map(|i| self::like(i, x, int)).collect()),
        _ => num(x),
    }
}

/// A numeric interval at the start of a range cell.
#[derive(Debug)]
struct Interval {
    lo: f64,
    hi: f64,
    lo_open: bool,
    hi_open: bool,
    int: bool,
}

fn interval(cell: &str) -> Option<Interval> {
    let s = cell.trim();
    let num = |t: &str| t.trim().replace('−', "-").parse::<f64>().ok();
    if let Some((a, b)) = s.split_once("..=") {
        let b: String = b.chars().take_while(|c| c.is_ascii_digit() || *c == '_').collect();
        return Some(Interval {
            lo: num(a)?,
            hi: num(&b.replace('_', ""))?,
            lo_open: false,
            hi_open: false,
            int: true,
        });
    }
    let lo_open = match s.chars().next()? {
        '[' => false,
        '(' => true,
        _ => return None,
    };
    let end = s.find([']', ')'])?;
    let hi_open = s[end..].starts_with(')');
    let (a, b) = s[1..end].split_once(',')?;
    Some(Interval {
        lo: num(a)?,
        hi: num(b)?,
        lo_open,
        hi_open,
        int: false,
    })
}

#[test]
fn every_shipped_config_key_is_documented() {
    let page = std::fs::read_to_string(root().join(PAGE)).unwrap_or_else(|e| panic!("{PAGE}: {e}"));
    let doc = rows(&page);
    for k in KINDS {
        assert!(
            page.lines().any(|l| l.starts_with(k.heading())),
            "{PAGE}: no section '{}'",
            k.heading()
        );
    }
    let files = shipped();
    let mut missing = Vec::new();
    for (path, kind, t) in &files {
        let mut keys = Vec::new();
        flatten(t, "", &mut keys);
        for key in keys {
            if !doc.iter().any(|r| r.kind == *kind && r.key == key) {
                missing.push(format!(
                    "{}: key `{key}` is not documented in {PAGE} (section '{}'): add a row \
                     | `{key}` | unit | default | range | meaning |",
                    path.display(),
                    kind.heading()
                ));
            }
        }
    }
    missing.dedup();
    assert!(missing.is_empty(), "undocumented keys:\n{}", missing.join("\n"));
}

#[test]
fn documented_config_keys_exist_with_their_defaults_and_ranges() {
    let page = std::fs::read_to_string(root().join(PAGE)).unwrap_or_else(|e| panic!("{PAGE}: {e}"));
    let doc = rows(&page);
    assert!(doc.len() > 100, "{PAGE}: only {} key rows found", doc.len());
    let files = shipped();
    let mut shipped_keys = Vec::new();
    for (_, kind, t) in &files {
        let mut keys = Vec::new();
        flatten(t, "", &mut keys);
        shipped_keys.extend(keys.into_iter().map(|k| (*kind, k)));
    }
    let mut defects = Vec::new();
    let mut checked = [0usize; 3];
    for r in &doc {
        let at = format!("{PAGE}:{} `{}` ({:?})", r.line, r.key, r.kind);
        let (_, kind, base) = base_for(&files, r.kind, &r.key);
        let kind = *kind;
        let mut ctx = base.clone();
        for (k, v) in assignments(&r.default).into_iter().chain(r.with.clone()) {
            set(&mut ctx, &k, v, &doc, kind);
        }
        // The key with its sample value must be accepted.
        let sample = sample_of(&r.default);
        let with = |v: Value| {
            let mut t = ctx.clone();
            set(&mut t, &r.key, v, &doc, kind);
            toml::to_string(&t).unwrap()
        };
        match &sample {
            Some(v) => {
                if let Err(e) = kind.parse(&with(v.clone())) {
                    defects.push(format!("{at}: the schema refuses it with its documented value: {e}"));
                    continue;
                }
            }
            None if shipped_keys.iter().any(|(k, key)| *k == r.kind && *key == r.key) => {}
            None => {
                defects.push(format!(
                    "{at}: cannot be checked: no shipped file sets it and its default cell gives \
                     neither a literal default nor an example (`e.g. `value``)"
                ));
                continue;
            }
        }
        // The documented default is what leaving the key out gives.
        if let Some(d) = default_of(&r.default) {
            // Its parents made as the check makes them, the key left out.
            let mut without = ctx.clone();
            set(&mut without, &r.key, d.clone(), &doc, kind);
            remove(&mut without, &r.key);
            let a = kind.parse(&toml::to_string(&without).unwrap());
            let b = kind.parse(&with(d.clone()));
            match (a, b) {
                (Ok(a), Ok(b)) if a == b => checked[0] += 1,
                (Ok(_), Ok(_)) => defects.push(format!("{at}: documented default {d} is not the code's default")),
                (Err(e), _) => defects.push(format!(
                    "{at}: documented default {d}, but leaving the key out is refused (required? write —): {e}"
                )),
                (_, Err(e)) => defects.push(format!("{at}: documented default {d} is refused: {e}")),
            }
        }
        // The documented range is the one enforced.
        let Some(iv) = interval(&r.range) else {
            // Choices: each accepted.
            let choices: Vec<Value> = ticks(&r.range)
                .iter()
                .filter(|s| s.starts_with('"'))
                .filter_map(|s| literal(s))
                .collect();
            // A choice of a tagged table (`kind`) may need sibling keys the
            // context lacks: only an error about the choice itself counts.
            if !choices.is_empty() {
                match kind.parse(&with(Value::String("no-such-choice".into()))) {
                    Err(e) if about(&e, &r.key) || e.msg.contains("unknown variant") => {}
                    other => defects.push(format!(
                        "{at}: a value outside the documented choices is not refused at the key: {other:?}"
                    )),
                }
            }
            for c in choices {
                match kind.parse(&with(c.clone())) {
                    Err(e) if about(&e, &r.key) || e.msg.contains("unknown variant") => {
                        defects.push(format!("{at}: documented choice {c} is refused: {e}"))
                    }
                    _ => {}
                }
            }
            continue;
        };
        let Some(shape) = sample.clone().or_else(|| lookup(base, &r.key)) else {
            defects.push(format!("{at}: a range but no value to test it with"));
            continue;
        };
        let span = (iv.hi - iv.lo).abs().max(1e-300);
        let nudge = |x: f64| (x.abs() * 1e-6).max(span * 1e-9);
        let inside = [
            if iv.lo_open { iv.lo + nudge(iv.lo) } else { iv.lo },
            if iv.hi_open { iv.hi - nudge(iv.hi) } else { iv.hi },
        ];
        let outside = [
            if iv.int {
                iv.lo - 1.0
            } else if iv.lo_open {
                iv.lo
            } else {
                iv.lo - nudge(iv.lo)
            },
            if iv.int {
                iv.hi + 1.0
            } else if iv.hi_open {
                iv.hi
            } else {
                iv.hi + nudge(iv.hi)
            },
        ];
        let mut judged = true;
        for x in inside {
            match kind.check(&with(like(&shape, x, iv.int))) {
                Ok(()) => {}
                Err(e) if about(&e, &r.key) => defects.push(format!(
                    "{at}: {x} is inside the documented range {} but refused: {e}",
                    r.range
                )),
                // Refused for another key: this base cannot judge the bounds.
                Err(_) => judged = false,
            }
        }
        if !judged {
            defects.push(format!(
                "{at}: the range {} cannot be checked: the file with the key at its bounds \
                 fails on another key (give the row a context, `path = value`)",
                r.range
            ));
            continue;
        }
        for x in outside {
            match kind.check(&with(like(&shape, x, iv.int))) {
                Err(e) if about(&e, &r.key) => {}
                Ok(()) => defects.push(format!(
                    "{at}: {x} is outside the documented range {} but accepted",
                    r.range
                )),
                Err(e) => defects.push(format!(
                    "{at}: {x} is outside the documented range {} and refused for another key: {e}",
                    r.range
                )),
            }
        }
        checked[1] += 1;
    }
    checked[2] = doc.len();
    println!(
        "{} rows: {} defaults and {} ranges checked against the code",
        checked[2], checked[0], checked[1]
    );
    assert!(defects.is_empty(), "{} defects:\n{}", defects.len(), defects.join("\n"));
}

/// The value at `key` in `t` (first element of arrays of tables).
fn lookup(t: &Table, key: &str) -> Option<Value> {
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = t;
    for p in &parts[..parts.len() - 1] {
        cur = match cur.get(*p)? {
            Value::Table(sub) => sub,
            Value::Array(items) => items.first()?.as_table()?,
            _ => return None,
        };
    }
    cur.get(parts[parts.len() - 1]).cloned()
}
