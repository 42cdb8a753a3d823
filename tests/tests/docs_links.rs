//! The user's documents hold together: every relative link of README.md, ARCHITECTURE.md,
//! results/RESULTS.md and the book (`docs/src`) reaches a file that exists, and a link to a
//! heading (`page.md#anchor`) reaches a heading that exists; the book's pages link only within
//! the book (mdBook serves nothing else); SUMMARY.md names every page and every page it names
//! exists. (`bash deploy/docs.sh` builds the book itself with mdBook.)

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The markdown files whose links are checked.
fn documents() -> Vec<PathBuf> {
    let root = repo();
    let mut files: Vec<PathBuf> = ["README.md", "ARCHITECTURE.md", "results/RESULTS.md"]
        .iter()
        .map(|f| root.join(f))
        .filter(|p| p.exists())
        .collect();
    files.extend(book_pages());
    files
}

/// Every markdown file under docs/src.
fn book_pages() -> Vec<PathBuf> {
    let mut pages = Vec::new();
    let mut dirs = vec![repo().join("docs/src")];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).expect("docs/src exists") {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "md") {
                pages.push(path);
            }
        }
    }
    pages.sort();
    pages
}

/// The text outside fenced code blocks and inline code spans (links there are not links).
fn prose(text: &str) -> String {
    let mut out = String::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if !fenced {
            let spans: Vec<&str> = line.split('`').collect();
            // Even pieces are outside code spans.
            for piece in spans.iter().step_by(2) {
                out.push_str(piece);
            }
            out.push('\n');
        }
    }
    out
}

/// Targets of `[text](target)` links.
fn links(text: &str) -> Vec<String> {
    let prose = prose(text);
    let mut found = Vec::new();
    let mut rest = prose.as_str();
    while let Some(at) = rest.find("](") {
        rest = &rest[at + 2..];
        if let Some(end) = rest.find(')') {
            let target = rest[..end].split_whitespace().next().unwrap_or("");
            found.push(target.to_string());
        }
    }
    found
}

/// mdBook's (and GitHub's) id of a heading: lower case, spaces to '-', other punctuation gone.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .chars()
        .filter_map(|c| {
            if c.is_alphanumeric() || c == '_' || c == '-' {
                Some(c.to_lowercase().next().unwrap_or(c))
            } else if c.is_whitespace() {
                Some('-')
            } else {
                None
            }
        })
        .collect()
}

/// The anchors of a markdown file's headings (outside code blocks).
fn anchors(path: &Path) -> BTreeSet<String> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let mut fenced = false;
    let mut found = BTreeSet::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else if !fenced && line.starts_with('#') {
            found.insert(anchor(line.trim_start_matches('#')));
        }
    }
    found
}

/// What is wrong with one link of `page`, if anything.
fn broken(page: &Path, target: &str, in_book: bool) -> Option<String> {
    let external = ["http://", "https://", "mailto:"];
    if external.iter().any(|p| target.starts_with(p)) || target.is_empty() {
        return None;
    }
    let (file, fragment) = target.split_once('#').unwrap_or((target, ""));
    let resolved = if file.is_empty() {
        page.to_path_buf()
    } else {
        page.parent().unwrap().join(file)
    };
    let resolved = resolved.canonicalize().ok();
    let book = repo().join("docs/src").canonicalize().unwrap();
    match resolved {
        None => Some(format!("{target}: no such file")),
        Some(p) if in_book && !p.starts_with(&book) => Some(format!(
            "{target}: outside the book (name the file in a code span)"
        )),
        Some(p) if !fragment.is_empty() && p.extension().is_some_and(|e| e == "md") => {
            (!anchors(&p).contains(fragment)).then(|| format!("{target}: no such heading"))
        }
        Some(_) => None,
    }
}

#[test]
fn every_relative_link_reaches_a_file_and_a_heading() {
    let book = repo().join("docs/src");
    let mut problems = Vec::new();
    for page in documents() {
        let text = std::fs::read_to_string(&page).unwrap();
        for target in links(&text) {
            if let Some(problem) = broken(&page, &target, page.starts_with(&book)) {
                problems.push(format!("{}: {problem}", page.display()));
            }
        }
    }
    assert!(
        problems.is_empty(),
        "broken links:\n{}",
        problems.join("\n")
    );
}

#[test]
fn the_summary_names_every_page_of_the_book_and_only_pages_that_exist() {
    let src = repo().join("docs/src");
    let summary = std::fs::read_to_string(src.join("SUMMARY.md")).unwrap();
    let named: BTreeSet<PathBuf> = links(&summary).iter().map(|l| src.join(l)).collect();
    let pages: BTreeSet<PathBuf> = book_pages()
        .into_iter()
        .filter(|p| !p.ends_with("SUMMARY.md"))
        .collect();
    let missing: Vec<_> = named.difference(&pages).collect();
    let unlisted: Vec<_> = pages.difference(&named).collect();
    assert!(
        missing.is_empty(),
        "SUMMARY.md names pages that do not exist: {missing:?}"
    );
    assert!(
        unlisted.is_empty(),
        "pages SUMMARY.md does not name: {unlisted:?}"
    );
}

#[test]
fn the_checker_finds_links_and_anchors_as_mdbook_makes_them() {
    let text = "See [a](a.md#two-words) and `[not](a link)`.\n```\n[no](x)\n```\n[b](../b.md)";
    assert_eq!(links(text), ["a.md#two-words", "../b.md"]);
    assert_eq!(
        anchor(" `[sac.threads]` and Two, words"),
        "sacthreads-and-two-words"
    );
    let page = repo().join("docs/src/SUMMARY.md");
    assert!(broken(&page, "no-such-page.md", true).is_some());
    assert!(
        broken(&page, "../../README.md", true).is_some(),
        "outside the book"
    );
    assert!(broken(&page, "reference/configuration.md#sac", true).is_none());
    assert!(broken(&page, "reference/configuration.md#no-such", true).is_some());
}
