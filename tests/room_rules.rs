//! The dependency rules between the engine's rooms (the top-level modules of
//! `engine/src`), checked against the code.
//!
//! [`RULES`] is the one table of which room may import which; `docs/ARCHITECTURE.md`
//! states it between `<!-- room-rules:begin -->` and `<!-- room-rules:end -->`, and a
//! test below fails when the two differ. [`EXCEPTIONS`] lists, file by file, the
//! imports that break the rules today, so that they stay visible and cannot spread:
//! the same arrow from another file fails, and an exception whose import is gone fails
//! too (remove it from both tables).
//!
//! What counts as an import: every `crate::<room>` path in code (`use` items, paths in
//! expressions and types, `crate::{a, b}` groups, and `super::` chains that reach the
//! crate root), after comments and string literals are blanked, so intra-doc links
//! (`[`crate::x`]`) do not count. Code under `#[cfg(test)]` (an inline item, or a
//! module file declared `#[cfg(test)] mod name;`, with everything below it) is test
//! code and may also use the rooms of a rule's third column.
//!
//! Plain text scanning, no engine code runs: `cargo test -p edgenerf-suite --test room_rules`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// `(room, may import, tests may also import)`. A room's own modules are always allowed.
const RULES: &[(&str, &[&str], &[&str])] = &[
    ("gpu", &[], &[]),
    ("rng", &[], &[]),
    ("data", &["mesh"], &[]),
    ("edges", &["data"], &[]),
    ("layout", &["gpu"], &[]),
    ("optim", &["gpu"], &["rng"]),
    ("viz", &["data"], &[]),
    ("field", &["gpu", "rng", "layout", "optim"], &[]),
    ("sampler", &["gpu", "layout"], &["rng"]),
    ("render", &["gpu", "rng", "layout"], &[]),
    ("loss", &["gpu", "layout"], &["rng", "field", "render"]),
    ("mesh", &["rng"], &[]),
    ("metrics", &["data", "edges", "viz", "mesh"], &[]),
    (
        "train",
        &["gpu", "rng", "data", "edges", "layout", "optim", "viz", "field", "sampler", "render", "loss", "metrics", "mesh"],
        &[],
    ),
];

/// `(from, to, file)`: imports the rules forbid that the code has today, to be removed.
const EXCEPTIONS: &[(&str, &str, &str)] = &[];

const DOC: &str = "docs/ARCHITECTURE.md";

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn rooms() -> BTreeSet<&'static str> {
    RULES.iter().map(|r| r.0).collect()
}

/// One reference from a file to another room.
#[derive(Clone, Debug)]
struct Import {
    /// Repository-relative path.
    file: String,
    line: usize,
    from: String,
    to: String,
    test_code: bool,
    /// The source line, trimmed.
    text: String,
}

fn rs_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).map(|e| e.unwrap().path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rs_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The module path of a file under `engine/src` (`metrics/geometry.rs` -> `[metrics,
/// geometry]`, `metrics/mod.rs` -> `[metrics]`, `lib.rs` -> `[]`).
fn module_path(rel: &Path) -> Vec<String> {
    let mut parts: Vec<String> = rel.iter().map(|c| c.to_string_lossy().into_owned()).collect();
    let last = parts.pop().unwrap();
    let stem = last.strip_suffix(".rs").unwrap().to_string();
    if stem != "mod" && !(parts.is_empty() && stem == "lib") {
        parts.push(stem);
    }
    parts
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// The source with comments and the contents of string and character literals replaced
/// by spaces (newlines kept, so char offsets map to the same lines).
fn code_only(src: &str) -> Vec<char> {
    let s: Vec<char> = src.chars().collect();
    let mut out = s.clone();
    let blank = |out: &mut Vec<char>, a: usize, b: usize| {
        for c in &mut out[a..b.min(s.len())] {
            if *c != '\n' {
                *c = ' ';
            }
        }
    };
    let mut i = 0;
    while i < s.len() {
        let c = s[i];
        let next = s.get(i + 1).copied();
        if c == '/' && next == Some('/') {
            let end = (i..s.len()).find(|&j| s[j] == '\n').unwrap_or(s.len());
            blank(&mut out, i, end);
            i = end;
        } else if c == '/' && next == Some('*') {
            let (mut depth, mut j) = (1, i + 2);
            while j < s.len() && depth > 0 {
                if s[j] == '/' && s.get(j + 1) == Some(&'*') {
                    depth += 1;
                    j += 2;
                } else if s[j] == '*' && s.get(j + 1) == Some(&'/') {
                    depth -= 1;
                    j += 2;
                } else {
                    j += 1;
                }
            }
            blank(&mut out, i, j);
            i = j;
        } else if c == 'r' && (i == 0 || !is_ident(s[i - 1]) || (s[i - 1] == 'b' && (i < 2 || !is_ident(s[i - 2])))) && matches!(next, Some('"') | Some('#')) {
            // Raw string r"..." / r#"..."#, or an identifier starting with r.
            let mut j = i + 1;
            while j < s.len() && s[j] == '#' {
                j += 1;
            }
            if j < s.len() && s[j] == '"' {
                let hashes = j - i - 1;
                let mut k = j + 1;
                while k < s.len() && !(s[k] == '"' && (0..hashes).all(|h| s.get(k + 1 + h) == Some(&'#'))) {
                    k += 1;
                }
                blank(&mut out, j + 1, k);
                i = k + 1 + hashes;
            } else {
                i += 1;
            }
        } else if c == '"' {
            let mut j = i + 1;
            while j < s.len() && s[j] != '"' {
                j += if s[j] == '\\' { 2 } else { 1 };
            }
            blank(&mut out, i + 1, j);
            i = j + 1;
        } else if c == '\'' {
            // A character literal ('x', '\n', '\u{..}'), else a lifetime or label.
            if next == Some('\\') {
                let mut j = i + 2;
                while j < s.len() && s[j] != '\'' {
                    j += 1;
                }
                blank(&mut out, i + 1, j);
                i = j + 1;
            } else if s.get(i + 2) == Some(&'\'') {
                blank(&mut out, i + 1, i + 2);
                i += 3;
            } else {
                i += 1;
            }
        } else {
            i += 1;
        }
    }
    out
}

fn line_of(code: &[char], at: usize) -> usize {
    1 + code[..at].iter().filter(|&&c| c == '\n').count()
}

fn skip_ws(code: &[char], mut i: usize) -> usize {
    while i < code.len() && code[i].is_whitespace() {
        i += 1;
    }
    i
}

fn ident_at(code: &[char], i: usize) -> String {
    code[i..].iter().take_while(|&&c| is_ident(c)).collect()
}

/// Index just past the bracket matching the one at `open`.
fn matching(code: &[char], open: usize) -> usize {
    let (o, c) = (code[open], match code[open] {
        '{' => '}',
        '[' => ']',
        '(' => ')',
        other => panic!("not a bracket: {other}"),
    });
    let mut depth = 0;
    for (j, &ch) in code.iter().enumerate().skip(open) {
        if ch == o {
            depth += 1;
        } else if ch == c {
            depth -= 1;
            if depth == 0 {
                return j + 1;
            }
        }
    }
    code.len()
}

/// Char ranges of items under `#[cfg(test)]`, and the names of `#[cfg(test)] mod name;`.
fn test_items(code: &[char]) -> (Vec<(usize, usize)>, Vec<String>) {
    let attr: Vec<char> = "#[cfg(test)]".chars().collect();
    let (mut ranges, mut mods) = (Vec::new(), Vec::new());
    let mut i = 0;
    while i + attr.len() <= code.len() {
        if code[i..i + attr.len()] != attr[..] {
            i += 1;
            continue;
        }
        let start = i;
        let mut j = skip_ws(code, i + attr.len());
        while code.get(j) == Some(&'#') && code.get(j + 1) == Some(&'[') {
            j = skip_ws(code, matching(code, j + 1));
        }
        // The item runs to its first `;` or through the block of its first `{`.
        let mut k = j;
        while k < code.len() && code[k] != ';' && code[k] != '{' {
            k += 1;
        }
        let end = if code.get(k) == Some(&'{') { matching(code, k) } else { k + 1 };
        let head: String = code[j..k.min(code.len())].iter().collect();
        let words: Vec<&str> = head.split_whitespace().collect();
        if code.get(k) == Some(&';') && words.len() >= 2 && words[words.len() - 2] == "mod" {
            mods.push(words[words.len() - 1].to_string());
        }
        ranges.push((start, end));
        i = end.max(start + 1);
    }
    (ranges, mods)
}

/// The rooms named after `crate::` at `i` (one, or several for a `{...}` group), with
/// the char index of each name.
fn rooms_after(code: &[char], i: usize, rooms: &BTreeSet<&str>) -> Vec<(String, usize)> {
    if code.get(i) == Some(&'{') {
        let end = matching(code, i);
        let mut out = Vec::new();
        let mut depth = 0;
        let mut expect_name = true;
        for j in i + 1..end - 1 {
            match code[j] {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => expect_name = true,
                c if expect_name && depth == 0 && is_ident(c) => {
                    expect_name = false;
                    let name = ident_at(code, j);
                    if rooms.contains(name.as_str()) {
                        out.push((name, j));
                    }
                }
                _ => {}
            }
        }
        out
    } else {
        let name = ident_at(code, i);
        if rooms.contains(name.as_str()) { vec![(name, i)] } else { Vec::new() }
    }
}

/// Every reference from a room's files to another room.
fn scan_engine() -> Vec<Import> {
    let root = repo();
    let src = root.join("engine/src");
    let rooms = rooms();
    let mut files = Vec::new();
    rs_files(&src, &mut files);
    let parsed: Vec<(PathBuf, Vec<String>, String, Vec<char>)> = files
        .iter()
        .map(|f| {
            let text = std::fs::read_to_string(f).unwrap();
            let code = code_only(&text);
            (f.clone(), module_path(f.strip_prefix(&src).unwrap()), text, code)
        })
        .collect();
    // Modules declared `#[cfg(test)] mod name;`: they and everything below are tests.
    let mut test_modules: BTreeSet<Vec<String>> = BTreeSet::new();
    for (_, module, _, code) in &parsed {
        for name in test_items(code).1 {
            let mut m = module.clone();
            m.push(name);
            test_modules.insert(m);
        }
    }
    let mut imports = Vec::new();
    let needle: Vec<char> = "crate::".chars().collect();
    for (file, module, text, code) in &parsed {
        let Some(room) = module.first() else { continue }; // lib.rs
        let rel = file.strip_prefix(&root).unwrap().to_string_lossy().into_owned();
        let lines: Vec<&str> = text.lines().collect();
        let test_file = (1..=module.len()).any(|n| test_modules.contains(&module[..n]));
        let test_ranges = test_items(code).0;
        let mut found: Vec<(String, usize)> = Vec::new();
        for i in 0..code.len().saturating_sub(needle.len()) {
            if code[i..i + needle.len()] == needle[..] && (i == 0 || !is_ident(code[i - 1])) {
                found.extend(rooms_after(code, i + needle.len(), &rooms));
            }
        }
        // `super::` chains that climb to the crate root (`use super::metrics` in viz.rs).
        let sup: Vec<char> = "super::".chars().collect();
        let mut i = 0;
        while i + sup.len() <= code.len() {
            if code[i..i + sup.len()] == sup[..] && (i == 0 || !is_ident(code[i - 1]) && code[i - 1] != ':') {
                let (mut j, mut ups) = (i, 0);
                while j + sup.len() <= code.len() && code[j..j + sup.len()] == sup[..] {
                    ups += 1;
                    j = skip_ws(code, j + sup.len());
                }
                if ups >= module.len() {
                    found.extend(rooms_after(code, j, &rooms));
                }
                i = j;
            } else {
                i += 1;
            }
        }
        for (to, at) in found {
            if &to == room {
                continue;
            }
            let line = line_of(code, at);
            imports.push(Import {
                file: rel.clone(),
                line,
                from: room.clone(),
                to,
                test_code: test_file || test_ranges.iter().any(|&(a, b)| a <= at && at < b),
                text: lines[line - 1].trim().to_string(),
            });
        }
    }
    imports
}

fn rule_of(room: &str) -> (&'static [&'static str], &'static [&'static str]) {
    let r = RULES.iter().find(|r| r.0 == room).unwrap_or_else(|| panic!("room {room} has no rule"));
    (r.1, r.2)
}

/// The imports the rules forbid (exceptions included), as messages.
fn violations(imports: &[Import]) -> Vec<(Import, String)> {
    let mut out = Vec::new();
    for imp in imports {
        let (allowed, test_allowed) = rule_of(&imp.from);
        if allowed.contains(&imp.to.as_str()) || (imp.test_code && test_allowed.contains(&imp.to.as_str())) {
            continue;
        }
        let mut may: Vec<&str> = allowed.to_vec();
        if imp.test_code {
            may.extend(test_allowed);
        }
        let may = if may.is_empty() { "no other room".to_string() } else { may.join(", ") };
        let kind = if imp.test_code { "test code of " } else { "" };
        out.push((
            imp.clone(),
            format!(
                "{}:{}: {kind}room `{}` uses room `{}`, which the rules forbid ({} may use: {may}; see {DOC})\n    {}",
                imp.file, imp.line, imp.from, imp.to, imp.from, imp.text
            ),
        ));
    }
    out
}

fn is_exception(imp: &Import) -> bool {
    EXCEPTIONS.iter().any(|&(from, to, file)| from == imp.from && to == imp.to && file == imp.file)
}

#[test]
fn rooms_import_only_what_the_rules_allow() {
    let imports = scan_engine();
    assert!(imports.len() > 50, "the scan found only {} cross-room references: is it broken?", imports.len());
    let bad: Vec<String> = violations(&imports).into_iter().filter(|(imp, _)| !is_exception(imp)).map(|(_, msg)| msg).collect();
    assert!(
        bad.is_empty(),
        "{} import(s) break the room rules (fix the import, or change the rule in tests/room_rules.rs and {DOC} together):\n{}",
        bad.len(),
        bad.join("\n")
    );
}

#[test]
fn every_exception_is_still_needed() {
    let imports = scan_engine();
    let used: BTreeSet<(String, String, String)> =
        violations(&imports).into_iter().map(|(i, _)| (i.from, i.to, i.file)).collect();
    let stale: Vec<String> = EXCEPTIONS
        .iter()
        .filter(|&&(from, to, file)| !used.contains(&(from.to_string(), to.to_string(), file.to_string())))
        .map(|(from, to, file)| format!("{from} -> {to} in {file}"))
        .collect();
    assert!(stale.is_empty(), "exceptions no longer used (remove them from tests/room_rules.rs and {DOC}):\n{}", stale.join("\n"));
}

#[test]
fn every_top_level_module_is_a_room_with_a_rule() {
    let lib = std::fs::read_to_string(repo().join("engine/src/lib.rs")).unwrap();
    let code: String = code_only(&lib).into_iter().collect();
    let declared: BTreeSet<String> = code
        .lines()
        .filter_map(|l| l.trim().strip_prefix("pub mod ").or_else(|| l.trim().strip_prefix("mod ")))
        .map(|m| m.trim_end_matches(';').trim().to_string())
        .collect();
    let ruled: BTreeSet<String> = rooms().iter().map(|r| r.to_string()).collect();
    assert_eq!(declared, ruled, "engine/src/lib.rs's modules and the rooms of RULES differ");
    for r in RULES {
        for to in r.1.iter().chain(r.2) {
            assert!(ruled.contains(*to), "rule of {}: unknown room {to}", r.0);
            assert_ne!(r.0, *to, "rule of {}: names itself", r.0);
        }
    }
}

/// The rows of the markdown table between `<!-- {marker}:begin -->` and `:end -->`,
/// each as its cells with backticks and spaces trimmed.
fn doc_table(doc: &str, marker: &str) -> Vec<Vec<String>> {
    let begin = format!("<!-- {marker}:begin -->");
    let end = format!("<!-- {marker}:end -->");
    let a = doc.find(&begin).unwrap_or_else(|| panic!("{DOC}: no `{begin}`"));
    let b = doc.find(&end).unwrap_or_else(|| panic!("{DOC}: no `{end}`"));
    doc[a + begin.len()..b]
        .lines()
        .map(str::trim)
        .filter(|l| l.starts_with('|'))
        .skip(2) // header and separator
        .map(|l| l.trim_matches('|').split('|').map(|c| c.trim().replace('`', "")).collect())
        .collect()
}

fn room_list(cell: &str) -> BTreeSet<String> {
    cell.split(',').map(str::trim).filter(|s| !s.is_empty() && *s != "-").map(str::to_string).collect()
}

#[test]
fn the_architecture_doc_states_the_same_rules_and_exceptions() {
    let doc = std::fs::read_to_string(repo().join(DOC)).unwrap();
    let doc_rules: BTreeMap<String, (BTreeSet<String>, BTreeSet<String>)> = doc_table(&doc, "room-rules")
        .into_iter()
        .map(|row| {
            assert_eq!(row.len(), 3, "{DOC}: a rules row has 3 cells: {row:?}");
            (row[0].clone(), (room_list(&row[1]), room_list(&row[2])))
        })
        .collect();
    let set = |rooms: &[&str]| rooms.iter().map(|s| s.to_string()).collect::<BTreeSet<_>>();
    let test_rules: BTreeMap<String, (BTreeSet<String>, BTreeSet<String>)> =
        RULES.iter().map(|r| (r.0.to_string(), (set(r.1), set(r.2)))).collect();
    assert_eq!(doc_rules, test_rules, "the rules table of {DOC} differs from RULES in tests/room_rules.rs");

    let doc_exceptions: BTreeSet<(String, String, String)> = doc_table(&doc, "room-exceptions")
        .into_iter()
        .map(|row| {
            assert!(row.len() >= 3, "{DOC}: an exceptions row has from, to, file, why: {row:?}");
            (row[0].clone(), row[1].clone(), row[2].clone())
        })
        .collect();
    let test_exceptions: BTreeSet<(String, String, String)> =
        EXCEPTIONS.iter().map(|&(a, b, c)| (a.to_string(), b.to_string(), c.to_string())).collect();
    assert_eq!(doc_exceptions, test_exceptions, "the exceptions table of {DOC} differs from EXCEPTIONS in tests/room_rules.rs");
}

/// Every path the doc names in backticks exists (a doc that matches the tree).
#[test]
fn every_path_the_architecture_doc_names_exists() {
    let root = repo();
    let doc = std::fs::read_to_string(root.join(DOC)).unwrap();
    let mut missing = Vec::new();
    for (n, line) in doc.lines().enumerate() {
        for (k, token) in line.split('`').enumerate() {
            let looks_like_path = k % 2 == 1
                && !token.is_empty()
                && token.chars().all(|c| is_ident(c) || "./-".contains(c))
                && token.contains('/'); // a bare name (`mod.rs`) is not a path
            if looks_like_path && !root.join(token).exists() {
                missing.push(format!("{DOC}:{}: `{token}`", n + 1));
            }
        }
    }
    assert!(missing.is_empty(), "paths named in {DOC} that do not exist (paths are relative to the repository root):\n{}", missing.join("\n"));
}

#[test]
fn the_scanner_sees_through_comments_strings_groups_and_test_modules() {
    let src = r##"
//! [`crate::train`] in a doc link
use crate::{gpu::Gpu, data::{Scene, Ray}};
/* crate::metrics in a block comment */
const S: &str = "crate::train";
const R: &str = r#"crate::train"#;
const C: char = '"';
fn f<'a>(x: &'a str) -> crate::layout::GpuRay { todo!() }
#[cfg(test)]
mod tests {
    use crate::render::Renderer;
}
#[cfg(test)]
mod more;
"##;
    let code = code_only(src);
    let flat: String = code.iter().collect();
    assert!(!flat.contains("crate::train") && !flat.contains("crate::metrics"), "{flat}");
    let rooms = rooms();
    let needle: Vec<char> = "crate::".chars().collect();
    let mut found = Vec::new();
    for i in 0..code.len() - needle.len() {
        if code[i..i + needle.len()] == needle[..] {
            found.extend(rooms_after(&code, i + needle.len(), &rooms).into_iter().map(|(r, at)| (r, line_of(&code, at))));
        }
    }
    let names: Vec<(&str, usize)> = found.iter().map(|(r, l)| (r.as_str(), *l)).collect();
    assert_eq!(names, [("gpu", 3), ("data", 3), ("layout", 8), ("render", 11)]);
    let (ranges, mods) = test_items(&code);
    assert_eq!(mods, ["more"]);
    let render_at = flat.find("crate::render").unwrap();
    assert!(ranges.iter().any(|&(a, b)| a <= render_at && render_at < b));
    assert!(!ranges.iter().any(|&(a, b)| a <= flat.find("crate::layout").unwrap() && flat.find("crate::layout").unwrap() < b));
}

/// Prints the current room graph (`-- --ignored --nocapture print_room_graph`): each
/// arrow with its number of references in code and in test code, and a first site.
#[test]
#[ignore]
fn print_room_graph() {
    let mut arrows: BTreeMap<(String, String), (usize, usize, String)> = BTreeMap::new();
    for imp in scan_engine() {
        let e = arrows.entry((imp.from.clone(), imp.to.clone())).or_insert((0, 0, format!("{}:{}", imp.file, imp.line)));
        if imp.test_code { e.1 += 1 } else { e.0 += 1 }
    }
    for ((from, to), (code, tests, first)) in arrows {
        println!("{from:>8} -> {to:<8} code {code:>3}  tests {tests:>3}  (first: {first})");
    }
}

/// Rooms whose own modules (the files and folders directly under `engine/src/<room>/`)
/// must import each other without a circle (`train`'s checkpoint / output / model circle
/// was untangled by `train/atomic_file.rs`).
const ACYCLIC_ROOMS: &[&str] = &["loss", "train"];

/// The arrows between the modules of `room` in code (not in `#[cfg(test)]` items or test
/// modules): `super::name` at a file's top level and `crate::<room>::name`, groups included.
fn module_arrows(room: &str) -> BTreeMap<String, BTreeSet<String>> {
    let src = repo().join("engine/src");
    let mut files = Vec::new();
    rs_files(&src.join(room), &mut files);
    let module_of = |f: &Path| module_path(f.strip_prefix(&src).unwrap());
    let siblings: BTreeSet<String> = files.iter().filter_map(|f| module_of(f).get(1).cloned()).collect();
    let names: BTreeSet<&str> = siblings.iter().map(String::as_str).collect();
    let parsed: Vec<(Vec<String>, Vec<char>)> =
        files.iter().map(|f| (module_of(f), code_only(&std::fs::read_to_string(f).unwrap()))).collect();
    let mut test_modules: BTreeSet<Vec<String>> = BTreeSet::new();
    for (module, code) in &parsed {
        for name in test_items(code).1 {
            test_modules.insert(module.iter().cloned().chain([name]).collect());
        }
    }
    let mut arrows: BTreeMap<String, BTreeSet<String>> = siblings.iter().map(|s| (s.clone(), BTreeSet::new())).collect();
    for (module, code) in &parsed {
        let Some(from) = module.get(1) else { continue }; // the room's mod.rs
        if (1..=module.len()).any(|n| test_modules.contains(&module[..n])) {
            continue;
        }
        let test_ranges = test_items(code).0;
        let mut found = Vec::new();
        for (needle, ups) in [(format!("crate::{room}::"), 0), ("super::".to_string(), module.len() - 1)] {
            let needle: Vec<char> = needle.chars().collect();
            let mut i = 0;
            while i + needle.len() <= code.len() {
                if code[i..i + needle.len()] != needle[..] || (i > 0 && (is_ident(code[i - 1]) || code[i - 1] == ':')) {
                    i += 1;
                    continue;
                }
                let (mut j, mut n) = (i, 0);
                while j + needle.len() <= code.len() && code[j..j + needle.len()] == needle[..] {
                    n += 1;
                    j = skip_ws(code, j + needle.len());
                }
                if ups == 0 || n == ups {
                    found.extend(rooms_after(code, j, &names).into_iter().filter(|&(_, at)| !test_ranges.iter().any(|&(a, b)| a <= at && at < b)));
                }
                i = j;
            }
        }
        for (to, _) in found {
            if &to != from {
                arrows.get_mut(from).unwrap().insert(to);
            }
        }
    }
    arrows
}

/// A circle of `arrows` (its modules in order, the first repeated at the end), if any.
fn find_circle(arrows: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(m: &str, arrows: &BTreeMap<String, BTreeSet<String>>, path: &mut Vec<String>, done: &mut BTreeSet<String>) -> Option<Vec<String>> {
        if let Some(at) = path.iter().position(|p| p == m) {
            return Some(path[at..].iter().cloned().chain([m.to_string()]).collect());
        }
        if !done.insert(m.to_string()) {
            return None;
        }
        path.push(m.to_string());
        for to in arrows.get(m).into_iter().flatten() {
            if let Some(c) = visit(to, arrows, path, done) {
                return Some(c);
            }
        }
        path.pop();
        None
    }
    let mut done = BTreeSet::new();
    arrows.keys().find_map(|m| visit(m, arrows, &mut Vec::new(), &mut done))
}

#[test]
fn the_modules_of_a_room_import_each_other_without_a_circle() {
    for room in ACYCLIC_ROOMS {
        let arrows = module_arrows(room);
        let n: usize = arrows.values().map(BTreeSet::len).sum();
        assert!(n >= 3, "the scan found only {n} arrows between the modules of {room}: is it broken? {arrows:?}");
        if let Some(circle) = find_circle(&arrows) {
            panic!("the modules of {room} import each other in a circle: {} (move what they share into a module below them)", circle.join(" -> "));
        }
    }
}
