//! Rules the code keeps that the compiler does not check (ARCHITECTURE.md states them):
//!
//! * inside a crate the files import one way: no file reaches itself again through `use
//!   crate::...` / `super::...` paths ([`import_loops`]);
//! * no function in library or binary code is over [`MAX_FUNCTION_LINES`] lines
//!   ([`long_functions`]); a longer numeric kernel says why in a `// long: <why>` comment
//!   right above it.
//!
//! Both read the source as text: a small lexer drops comments and string and char literals,
//! so braces and paths inside them are never counted. `#[cfg(test)]` modules and the files
//! under `tests/`, `benches/` and `examples/` are left out (tests and examples aside).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The longest a function may be, counting its signature's first line to its closing brace.
pub const MAX_FUNCTION_LINES: usize = 80;

/// The marker a longer function carries right above it, with the reason after it.
pub const LONG_MARKER: &str = "// long:";

/// One source file of a crate: its module path (`""` for the crate root) and its code with
/// comments, literals and `#[cfg(test)]` modules blanked out (line structure kept).
pub struct SourceFile {
    /// Path on disk.
    pub path: PathBuf,
    /// Module path inside its crate, `a::b` (the root is `""`).
    pub module: String,
    /// The text as written.
    pub text: String,
    /// The code only: comments and literals replaced by spaces, newlines kept.
    pub code: String,
}

impl SourceFile {
    /// The file at `path` of module `module` with contents `text`.
    pub fn new(path: PathBuf, module: String, text: String) -> Self {
        let code = blank_test_modules(&strip_comments_and_literals(&text));
        Self {
            path,
            module,
            text,
            code,
        }
    }
}

/// The library and binary crates of the workspace: `common/*` and `services/*`.
pub fn workspace_crates(root: &Path) -> Vec<PathBuf> {
    let mut crates = Vec::new();
    for group in ["common", "services"] {
        let Ok(entries) = std::fs::read_dir(root.join(group)) else {
            continue;
        };
        for e in entries.flatten() {
            if e.path().join("Cargo.toml").is_file() && e.path().join("src").is_dir() {
                crates.push(e.path());
            }
        }
    }
    crates.sort();
    crates
}

/// Every `.rs` file under `<crate>/src`, with its module path.
pub fn crate_files(krate: &Path) -> Vec<SourceFile> {
    let src = krate.join("src");
    let mut files = Vec::new();
    let mut stack = vec![src.clone()];
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let text = std::fs::read_to_string(&p).unwrap_or_default();
                let module = module_path(&src, &p);
                files.push(SourceFile::new(p, module, text));
            }
        }
    }
    files.sort_by(|a, b| a.path.cmp(&b.path));
    files
}

/// `src/a/b.rs` -> `a::b`, `src/a/mod.rs` -> `a`, `src/lib.rs` and `src/main.rs` -> `""`
/// (a file under `src/bin/` is a crate root of its own: `bin::name`, never imported).
fn module_path(src: &Path, file: &Path) -> String {
    let rel = file.strip_prefix(src).unwrap_or(file);
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().trim_end_matches(".rs").to_string())
        .collect();
    if matches!(parts.last().map(String::as_str), Some("mod")) {
        parts.pop();
    }
    if parts.len() == 1 && matches!(parts[0].as_str(), "lib" | "main") {
        parts.clear();
    }
    parts.join("::")
}

/// The text with comments, string, byte-string, raw-string and char literals replaced by
/// spaces (newlines kept, so line numbers still match).
pub fn strip_comments_and_literals(text: &str) -> String {
    let c: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    let blank = |out: &mut String, ch: char| out.push(if ch == '\n' { '\n' } else { ' ' });
    while i < c.len() {
        let next = c.get(i + 1).copied();
        if c[i] == '/' && next == Some('/') {
            while i < c.len() && c[i] != '\n' {
                blank(&mut out, c[i]);
                i += 1;
            }
        } else if c[i] == '/' && next == Some('*') {
            let mut depth = 0;
            while i < c.len() {
                if c[i] == '/' && c.get(i + 1) == Some(&'*') {
                    depth += 1;
                    out.push_str("  ");
                    i += 2;
                } else if c[i] == '*' && c.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    out.push_str("  ");
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    blank(&mut out, c[i]);
                    i += 1;
                }
            }
        } else if let Some(end) = raw_string_end(&c, i) {
            (i..end).for_each(|k| blank(&mut out, c[k]));
            i = end;
        } else if c[i] == '"' {
            i = skip_quoted(&c, i, '"', &mut out);
        } else if c[i] == '\'' && is_char_literal(&c, i) {
            i = skip_quoted(&c, i, '\'', &mut out);
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    out
}

/// Where a raw string starting at `i` (`r"`, `r#"`, `br#"`) ends, if one starts there.
fn raw_string_end(c: &[char], i: usize) -> Option<usize> {
    let prev_ident = i > 0 && (c[i - 1].is_alphanumeric() || c[i - 1] == '_');
    let mut j = i;
    if c.get(j) == Some(&'b') {
        j += 1;
    }
    if prev_ident || c.get(j) != Some(&'r') {
        return None;
    }
    j += 1;
    let hashes = c[j..].iter().take_while(|&&ch| ch == '#').count();
    j += hashes;
    if c.get(j) != Some(&'"') {
        return None;
    }
    j += 1;
    while j < c.len() {
        if c[j] == '"'
            && c[j + 1..]
                .iter()
                .take(hashes)
                .filter(|&&h| h == '#')
                .count()
                == hashes
        {
            return Some(j + 1 + hashes);
        }
        j += 1;
    }
    Some(c.len())
}

/// A `'` that opens a char literal (`'a'`, `'\n'`, `'\u{..}'`) rather than a lifetime.
fn is_char_literal(c: &[char], i: usize) -> bool {
    matches!(
        (c.get(i + 1), c.get(i + 2)),
        (Some('\\'), _) | (Some(_), Some('\''))
    )
}

/// Blank a literal delimited by `quote` starting at `i`; returns the index after it.
fn skip_quoted(c: &[char], mut i: usize, quote: char, out: &mut String) -> usize {
    out.push(' ');
    i += 1;
    while i < c.len() {
        let ch = c[i];
        if ch == '\\' {
            out.push(' ');
            if let Some(&n) = c.get(i + 1) {
                out.push(if n == '\n' { '\n' } else { ' ' });
            }
            i += 2;
            continue;
        }
        out.push(if ch == '\n' { '\n' } else { ' ' });
        i += 1;
        if ch == quote {
            break;
        }
    }
    i
}

/// The code with every `#[cfg(test)]`-gated module body blanked (tests aside).
fn blank_test_modules(code: &str) -> String {
    let mut out: Vec<char> = code.chars().collect();
    let mut from = 0;
    while let Some(at) = find_from(&out, "#[cfg(test)]", from) {
        from = at + 1;
        let rest: String = out[at..].iter().take(200).collect();
        let after_attr = rest["#[cfg(test)]".len()..].trim_start();
        let after_pub = ["pub(crate) ", "pub(super) ", "pub "]
            .iter()
            .find_map(|p| after_attr.strip_prefix(p))
            .unwrap_or(after_attr);
        if !after_pub.trim_start().starts_with("mod ") {
            continue;
        }
        let Some(open) = out[at..].iter().position(|&ch| ch == '{' || ch == ';') else {
            break;
        };
        if out[at + open] == ';' {
            continue;
        }
        let close = matching_brace(&out, at + open).unwrap_or(out.len() - 1);
        for ch in &mut out[at..=close] {
            if *ch != '\n' {
                *ch = ' ';
            }
        }
    }
    out.into_iter().collect()
}

fn find_from(hay: &[char], needle: &str, from: usize) -> Option<usize> {
    let n: Vec<char> = needle.chars().collect();
    (from..hay.len().saturating_sub(n.len() - 1)).find(|&i| hay[i..i + n.len()] == n[..])
}

/// The index of the `}` that closes the `{` at `open`.
fn matching_brace(c: &[char], open: usize) -> Option<usize> {
    let mut depth = 0usize;
    for (k, &ch) in c.iter().enumerate().skip(open) {
        match ch {
            '{' => depth += 1,
            '}' => {
                depth -= 1;
                if depth == 0 {
                    return Some(k);
                }
            }
            _ => {}
        }
    }
    None
}

/// A function longer than the rule allows.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct LongFunction {
    /// The file, relative to the workspace root.
    pub file: String,
    /// The function's name.
    pub name: String,
    /// Its first line (1-based).
    pub line: usize,
    /// Its length in lines, signature to closing brace.
    pub lines: usize,
}

/// Every function in `file` over [`MAX_FUNCTION_LINES`] lines that has no [`LONG_MARKER`]
/// comment right above it (above its attributes and doc comments).
pub fn long_functions(file: &SourceFile, root: &Path) -> Vec<LongFunction> {
    let chars: Vec<char> = file.code.chars().collect();
    let line_of = line_index(&chars);
    let text_lines: Vec<&str> = file.text.lines().collect();
    let mut found = Vec::new();
    for at in fn_keywords(&chars) {
        let Some(name) = ident_after(&chars, at + 2) else {
            continue;
        };
        let Some(open) = body_start(&chars, at) else {
            continue;
        };
        let Some(close) = matching_brace(&chars, open) else {
            continue;
        };
        let (first, last) = (line_of[at], line_of[close]);
        let lines = last - first + 1;
        if lines > MAX_FUNCTION_LINES && !marked_long(&text_lines, first) {
            let file = file.path.strip_prefix(root).unwrap_or(&file.path);
            found.push(LongFunction {
                file: file.display().to_string(),
                name,
                line: first + 1,
                lines,
            });
        }
    }
    found
}

/// The 0-based line of every char.
fn line_index(c: &[char]) -> Vec<usize> {
    let mut line = 0;
    c.iter()
        .map(|&ch| {
            let l = line;
            if ch == '\n' {
                line += 1;
            }
            l
        })
        .collect()
}

/// Positions of the keyword `fn` (not part of an identifier, not `Fn`/`fn(` types).
fn fn_keywords(c: &[char]) -> Vec<usize> {
    let is_ident = |ch: char| ch.is_alphanumeric() || ch == '_';
    (0..c.len().saturating_sub(2))
        .filter(|&i| {
            c[i] == 'f'
                && c[i + 1] == 'n'
                && c[i + 2].is_whitespace()
                && (i == 0 || !is_ident(c[i - 1]))
        })
        .collect()
}

fn ident_after(c: &[char], from: usize) -> Option<String> {
    let start = (from..c.len()).find(|&i| !c[i].is_whitespace())?;
    let name: String = c[start..]
        .iter()
        .take_while(|ch| ch.is_alphanumeric() || **ch == '_')
        .collect();
    (!name.is_empty()).then_some(name)
}

/// The `{` opening the body of the function whose `fn` is at `at`, or `None` for a
/// declaration without a body (a trait method ending in `;`). Parentheses, brackets and
/// generics' angle brackets are skipped, so a `{` in a default type or a const generic block
/// is not taken for the body.
fn body_start(c: &[char], at: usize) -> Option<usize> {
    let mut depth = 0i32;
    for (k, &ch) in c.iter().enumerate().skip(at) {
        match ch {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            '{' if depth == 0 => return Some(k),
            ';' if depth == 0 => return None,
            _ => {}
        }
    }
    None
}

/// The function starting at 0-based `line` has the marker above it, above any attributes and
/// doc comments it has.
fn marked_long(lines: &[&str], line: usize) -> bool {
    let mut l = line;
    while l > 0 {
        l -= 1;
        let t = lines[l].trim_start();
        if t.starts_with(LONG_MARKER) {
            return true;
        }
        if !(t.starts_with("///") || t.starts_with("#[") || t.starts_with("//")) {
            return false;
        }
    }
    false
}

/// One import of a file: the module it names and the line it is on (1-based).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Import {
    /// The module imported from (`""`: the crate root itself).
    pub to: String,
    /// Where.
    pub line: usize,
}

/// The modules each file of a crate imports from (module path -> imports), following `crate::`
/// and `super::` paths (in `use` trees and in code). A name the crate root re-exports
/// (`pub use m::{A, B}` in `lib.rs`) counts as an import of `m`; a glob of the root
/// (`crate::*`) as an import of every module the root re-exports from.
pub fn import_graph(files: &[SourceFile]) -> BTreeMap<String, BTreeSet<Import>> {
    let modules: BTreeSet<String> = files.iter().map(|f| f.module.clone()).collect();
    let reexports = files
        .iter()
        .find(|f| f.module.is_empty())
        .map(|root| root_reexports(&root.code))
        .unwrap_or_default();
    let mut graph = BTreeMap::new();
    for f in files {
        let mut imports = BTreeSet::new();
        for (path, line, inline_depth) in paths_in(&f.code) {
            let Some(abs) = absolute(&f.module, &path, inline_depth) else {
                continue;
            };
            for to in resolve(&abs, &modules, &reexports) {
                if to != f.module && !f.module.starts_with(&format!("{to}::")) {
                    imports.insert(Import { to, line });
                }
            }
        }
        graph.insert(f.module.clone(), imports);
    }
    graph
}

/// Every path starting with `crate::` or `super::` in the code, expanded out of `use` trees
/// (`crate::{a::B, c}` -> `crate::a::B`, `crate::c`), with its line and how many inline
/// `mod name { ... }` blocks of the file enclose it (their `super` is the file's own module).
fn paths_in(code: &str) -> Vec<(Vec<String>, usize, usize)> {
    let c: Vec<char> = code.chars().collect();
    let line_of = line_index(&c);
    let inline_mods = inline_module_ranges(&c);
    let depth_at = |i: usize| inline_mods.iter().filter(|(a, b)| *a < i && i < *b).count();
    let mut out = Vec::new();
    let is_ident = |ch: char| ch.is_alphanumeric() || ch == '_';
    let mut i = 0;
    while i < c.len() {
        let starts = ["crate::", "super::"]
            .iter()
            .any(|p| c[i..].iter().take(p.len()).copied().eq(p.chars()));
        if !starts || (i > 0 && (is_ident(c[i - 1]) || c[i - 1] == ':')) {
            i += 1;
            continue;
        }
        let (tree, end) = take_use_tree(&c, i);
        for path in expand_tree(&tree) {
            out.push((path, line_of[i] + 1, depth_at(i)));
        }
        i = end.max(i + 1);
    }
    out
}

/// The brace ranges of the inline modules (`mod name {`) in the code.
fn inline_module_ranges(c: &[char]) -> Vec<(usize, usize)> {
    let is_ident = |ch: char| ch.is_alphanumeric() || ch == '_';
    let mut out = Vec::new();
    for i in 0..c.len().saturating_sub(4) {
        let keyword = c[i..i + 4].iter().copied().eq("mod ".chars());
        if !keyword || (i > 0 && is_ident(c[i - 1])) {
            continue;
        }
        let Some(name) = ident_after(c, i + 3) else {
            continue;
        };
        let after = (i + 4..c.len())
            .find(|&k| !c[k].is_whitespace())
            .unwrap_or(c.len());
        let open = after + name.chars().count();
        let open = (open..c.len())
            .find(|&k| !c[k].is_whitespace())
            .unwrap_or(c.len());
        if c.get(open) == Some(&'{') {
            if let Some(close) = matching_brace(c, open) {
                out.push((open, close));
            }
        }
    }
    out
}

/// The path or use tree starting at `i` (identifiers, `::`, braces, commas, `*`, `self`,
/// `as`), without whitespace; and where it ends.
fn take_use_tree(c: &[char], mut i: usize) -> (String, usize) {
    let mut tree = String::new();
    let mut depth = 0;
    while i < c.len() {
        let ch = c[i];
        let ok = ch.is_alphanumeric() || matches!(ch, '_' | ':' | '*');
        if ok {
            tree.push(ch);
        } else if ch == '{' {
            depth += 1;
            tree.push(ch);
        } else if ch == '}' && depth > 0 {
            depth -= 1;
            tree.push(ch);
        } else if ch == ',' && depth > 0 {
            tree.push(ch);
        } else if ch.is_whitespace() && depth > 0 {
            tree.push(' ');
        } else {
            break;
        }
        i += 1;
    }
    (tree, i)
}

/// `a::{b::C, d as E, *}` -> `[a,b,C]`, `[a,d]`, `[a,*]` (an alias drops its new name).
fn expand_tree(tree: &str) -> Vec<Vec<String>> {
    let tree = tree.trim().trim_end_matches("::");
    let Some(open) = tree.find('{') else {
        let first = tree.split_whitespace().next().unwrap_or("");
        let path = first
            .split("::")
            .filter(|s| !s.is_empty())
            .map(String::from);
        return vec![path.collect()];
    };
    let prefix: Vec<String> = tree[..open]
        .split("::")
        .filter(|s| !s.is_empty())
        .map(String::from)
        .collect();
    let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
    let mut out = Vec::new();
    for part in split_top_level(inner) {
        for mut tail in expand_tree(part) {
            if tail.first().is_some_and(|s| s == "self") {
                tail.remove(0);
            }
            let mut path = prefix.clone();
            path.extend(tail);
            out.push(path);
        }
    }
    out
}

fn split_top_level(s: &str) -> Vec<&str> {
    let (mut parts, mut depth, mut start) = (Vec::new(), 0, 0);
    for (k, ch) in s.char_indices() {
        match ch {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&s[start..k]);
                start = k + 1;
            }
            _ => {}
        }
    }
    parts.push(&s[start..]);
    parts.into_iter().filter(|p| !p.trim().is_empty()).collect()
}

/// `path` (starting `crate` or `super`) as segments from the crate root; `inline_depth`
/// inline modules enclose it, whose `super`s stay inside the file.
fn absolute(module: &str, path: &[String], inline_depth: usize) -> Option<Vec<String>> {
    let mut base: Vec<String> = match module {
        "" => Vec::new(),
        m => m.split("::").map(String::from).collect(),
    };
    // `super` in a file `a/b.rs` (module a::b) names a; in `a/mod.rs` (module a) the root.
    let mut rest = path;
    match rest.first().map(String::as_str) {
        Some("crate") => {
            base.clear();
            rest = &rest[1..];
        }
        Some("super") => {
            let mut inline = inline_depth;
            while rest.first().is_some_and(|s| s == "super") {
                match inline {
                    0 => drop(base.pop()?),
                    _ => inline -= 1,
                }
                rest = &rest[1..];
            }
        }
        _ => return None,
    }
    base.extend(rest.iter().cloned());
    Some(base)
}

/// The modules an absolute path imports from: the longest prefix that is a module file, or
/// for the root's own names, the modules the root re-exports them from.
fn resolve(
    abs: &[String],
    modules: &BTreeSet<String>,
    reexports: &BTreeMap<String, String>,
) -> Vec<String> {
    let longest = (1..=abs.len())
        .rev()
        .map(|n| abs[..n].join("::"))
        .find(|m| modules.contains(m));
    if let Some(m) = longest {
        return vec![m];
    }
    match abs.first().map(String::as_str) {
        Some("*") => reexports
            .values()
            .cloned()
            .collect::<BTreeSet<_>>()
            .into_iter()
            .collect(),
        Some(name) => reexports.get(name).cloned().into_iter().collect(),
        None => Vec::new(),
    }
}

/// Names the crate root re-exports, with the module each comes from (`pub use m::{A, B};`).
fn root_reexports(code: &str) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for stmt in code.split(';') {
        let s = stmt.trim();
        let Some(tree) = s.strip_prefix("pub use ") else {
            continue;
        };
        for path in expand_tree(tree) {
            let path: Vec<&str> = path.iter().map(String::as_str).collect();
            let from = match path.first() {
                Some(&"crate") | Some(&"self") => path.get(1),
                first => first,
            };
            if let (Some(from), Some(name)) = (from, path.last()) {
                out.insert(name.to_string(), from.to_string());
            }
        }
    }
    out
}

/// The import loops of a crate: each strongly connected set of two or more modules, with the
/// imports that close it (`from -> to (line)`).
pub fn import_loops(graph: &BTreeMap<String, BTreeSet<Import>>) -> Vec<Vec<String>> {
    let names: Vec<&String> = graph.keys().collect();
    let index: BTreeMap<&String, usize> = names.iter().enumerate().map(|(i, n)| (*n, i)).collect();
    let edges: Vec<Vec<usize>> = names
        .iter()
        .map(|n| {
            graph[*n]
                .iter()
                .filter_map(|imp| index.get(&imp.to).copied())
                .collect()
        })
        .collect();
    let mut loops = Vec::new();
    for scc in strongly_connected(&edges) {
        if scc.len() < 2 {
            continue;
        }
        let members: BTreeSet<usize> = scc.iter().copied().collect();
        let mut described = Vec::new();
        for &m in &scc {
            for imp in &graph[names[m]] {
                if index.get(&imp.to).is_some_and(|t| members.contains(t)) {
                    let show = |s: &str| {
                        if s.is_empty() {
                            "lib.rs".to_string()
                        } else {
                            s.to_string()
                        }
                    };
                    described.push(format!(
                        "{} -> {} (line {})",
                        show(names[m]),
                        show(&imp.to),
                        imp.line
                    ));
                }
            }
        }
        loops.push(described);
    }
    loops
}

/// Tarjan's strongly connected components of a graph given as adjacency lists.
fn strongly_connected(edges: &[Vec<usize>]) -> Vec<Vec<usize>> {
    struct State<'a> {
        edges: &'a [Vec<usize>],
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on_stack: Vec<bool>,
        stack: Vec<usize>,
        next: usize,
        out: Vec<Vec<usize>>,
    }
    fn visit(s: &mut State, v: usize) {
        s.index[v] = Some(s.next);
        s.low[v] = s.next;
        s.next += 1;
        s.stack.push(v);
        s.on_stack[v] = true;
        for k in 0..s.edges[v].len() {
            let w = s.edges[v][k];
            match s.index[w] {
                None => {
                    visit(s, w);
                    s.low[v] = s.low[v].min(s.low[w]);
                }
                Some(iw) if s.on_stack[w] => s.low[v] = s.low[v].min(iw),
                _ => {}
            }
        }
        if Some(s.low[v]) == s.index[v] {
            let mut scc = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack[w] = false;
                scc.push(w);
                if w == v {
                    break;
                }
            }
            s.out.push(scc);
        }
    }
    let n = edges.len();
    let mut s = State {
        edges,
        index: vec![None; n],
        low: vec![0; n],
        on_stack: vec![false; n],
        stack: Vec::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in 0..n {
        if s.index[v].is_none() {
            visit(&mut s, v);
        }
    }
    s.out
}
