//! Every `§n` citation of the numerical reference resolves inside the repository.
//!
//! Code comments cite sections of `docs/algorithm.md` as `§n`, `ALGORITHM §n` or
//! `ALGORITHM.md §n` (e.g. `§2.12`, `§7.1.2`). This test walks `src/`, `tests/`, `examples/` and
//! `benches/` (every `.rs` and `.md` file, except this one, whose examples are deliberately
//! bogus) plus `docs/algorithm.md` itself, extracts every citation of the reference and checks
//! that its number is the number of a heading of `docs/algorithm.md` (a line starting with `#`
//! outside a fenced code block; the number is the first token after the hashes, a trailing `.`
//! allowed). A second test checks that no heading number is used twice.
//!
//! # Which `§n` is a citation of the reference
//!
//! A citation is `§` + optional space + a number `d(.d)*`, optionally a range `–`/`—`/`-` +
//! optional `§` + number (`§2.6–2.9`, `§1.1–§1.3`: every number of the range must exist when the
//! two ends differ only in their last component, otherwise both ends). It is **not** a citation
//! of the reference — it is a section of another work, and is skipped — when, on the same line:
//!
//! 1. it continues a list (`, ` `/` `&` `and` `or` between it and the previous citation, as in
//!    `[Su21] §7.1.3, §7.1.4`): it is classified like the previous citation; otherwise
//! 2. the text right before it (whitespace, opening parentheses and backticks stripped) ends with
//!    `ALGORITHM` or `ALGORITHM.md`: a citation of the reference (this rule wins over 3–7);
//! 3. that text ends with a paper tag `[Key]` or `\[Key\]` (rustdoc escapes), where `Key` is one
//!    of the reference keys of the "References" list of `docs/algorithm.md` (`* **[Key]** …`):
//!    `[Su21] §7.1.4`, `\[Li\] §4.2`;
//! 4. that text ends with a year (`19xx`/`20xx`, optionally followed by `,` or `)`): an
//!    author–year citation, `Stomakhin et al. 2013 §8`;
//! 5. that text ends with `et al.`: `Su et al. §4`;
//! 6. that text ends with the name of another project document (`STYLE`, `README`,
//!    `BENCHMARKS`, `CHANGELOG`, `CONTRIBUTING`, optionally `.md`): `STYLE §7 item 10`;
//! 7. that text ends with an italic title `*Title*` (optionally followed by `,`):
//!    `*Real-Time Collision Detection*, §5.1.5`;
//! 8. it lies inside a parenthesis opened right after a paper tag and not closed before it, with
//!    no `ALGORITHM` in between: `[Su21] (§4, eq. 14)`, `\[Li\] (Li, Gao, …, Qin, §4.2`.
//!
//! Everything else is a citation of the reference and must resolve. A paper tag on the previous
//! line does not count: write the tag and the section sign on one line.
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

/// Directories walked for citations (relative to the crate root).
const SCANNED_DIRS: [&str; 4] = ["src", "tests", "examples", "benches"];
/// The numerical reference whose headings the citations must hit.
const REFERENCE: &str = "docs/algorithm.md";
/// This file: its unit tests hold bogus citations on purpose.
const THIS_FILE: &str = "tests/it/citations.rs";
/// Other project documents whose sections may be cited as `NAME §n` (rule 6).
const OTHER_DOCUMENTS: [&str; 5] = ["STYLE", "README", "BENCHMARKS", "CHANGELOG", "CONTRIBUTING"];

/// A section number such as `2.12`, as its components.
type Section = Vec<u32>;

fn show(s: &[u32]) -> String {
    s.iter().map(u32::to_string).collect::<Vec<_>>().join(".")
}

/// One `§` citation found in a line.
#[derive(Debug, Clone, PartialEq)]
struct Citation {
    /// The citation as written, e.g. `§2.6–2.9`.
    text: String,
    /// The sections it names (a range expanded).
    sections: Vec<Section>,
    /// True for a section of another work (rules 1–8 of the module docs).
    external: bool,
}

/// Parses `d(.d)*` at the start of `s`; returns the number and the bytes consumed. A `.` that is
/// not followed by a digit ends the number (`§2.5.` cites 2.5).
fn parse_number(s: &str) -> Option<(Section, usize)> {
    let b = s.as_bytes();
    let mut i = 0;
    let mut parts = Vec::new();
    loop {
        let start = i;
        while i < b.len() && b[i].is_ascii_digit() {
            i += 1;
        }
        if i == start {
            return None;
        }
        parts.push(s[start..i].parse().ok()?);
        if i + 1 < b.len() && b[i] == b'.' && b[i + 1].is_ascii_digit() {
            i += 1;
        } else {
            return Some((parts, i));
        }
    }
}

/// The range end after a number: `–2.9`, ` – §2.9`, `-2.9`; returns it and the bytes consumed.
fn parse_range_end(s: &str) -> Option<(Section, usize)> {
    let t = s.trim_start();
    let mut used = s.len() - t.len();
    let dash = ['–', '—', '-'].into_iter().find(|d| t.starts_with(*d))?;
    let t2 = &t[dash.len_utf8()..];
    used += dash.len_utf8();
    let t3 = t2.trim_start();
    used += t2.len() - t3.len();
    let t4 = t3.strip_prefix('§').unwrap_or(t3);
    used += t3.len() - t4.len();
    let t5 = t4.trim_start();
    used += t4.len() - t5.len();
    let (n, k) = parse_number(t5)?;
    Some((n, used + k))
}

/// The sections of a range `a`–`b`: all of them when the ends differ only in an increasing last
/// component (at most 50 apart), else just the two ends.
fn expand_range(a: Section, b: Section) -> Vec<Section> {
    let same_prefix = a.len() == b.len() && a[..a.len() - 1] == b[..b.len() - 1];
    let (x, y) = (a[a.len() - 1], b[b.len() - 1]);
    if same_prefix && y > x && y - x <= 50 {
        (x..=y)
            .map(|k| {
                let mut s = a.clone();
                *s.last_mut().unwrap() = k;
                s
            })
            .collect()
    } else {
        vec![a, b]
    }
}

/// If `p` ends with a paper tag `[Key]` or `\[Key\]` with `Key` in `tags`, the byte index where
/// the tag starts.
fn tag_at_end(p: &str, tags: &[String]) -> Option<usize> {
    let q = p.strip_suffix(']')?;
    let q = q.strip_suffix('\\').unwrap_or(q);
    let open = q.rfind('[')?;
    let key = &q[open + 1..];
    if !tags.iter().any(|t| t == key) {
        return None;
    }
    Some(if q[..open].ends_with('\\') {
        open - 1
    } else {
        open
    })
}

/// Rule 4: `p` ends with a year 19xx/20xx (optionally followed by `,` or `)`).
fn ends_with_year(p: &str) -> bool {
    let q = p.strip_suffix([',', ')']).unwrap_or(p);
    let b = q.as_bytes();
    if b.len() < 4 {
        return false;
    }
    let y = &b[b.len() - 4..];
    y.iter().all(u8::is_ascii_digit)
        && (y.starts_with(b"19") || y.starts_with(b"20"))
        && (b.len() == 4 || !b[b.len() - 5].is_ascii_alphanumeric())
}

/// Rule 6: `p` ends with the name of another project document.
fn ends_with_other_document(p: &str) -> bool {
    let q = p.strip_suffix(".md").unwrap_or(p);
    OTHER_DOCUMENTS.iter().any(|name| {
        q.strip_suffix(name)
            .is_some_and(|rest| !rest.chars().next_back().is_some_and(char::is_alphanumeric))
    })
}

/// Rule 7: `p` ends with an italic title `*Title*` (optionally followed by `,`); `**bold**` and
/// a list bullet `* ` do not count.
fn ends_with_italic_title(p: &str) -> bool {
    let q = p.strip_suffix(',').unwrap_or(p);
    let Some(inner) = q.strip_suffix('*') else {
        return false;
    };
    if inner.ends_with('*') || inner.ends_with(char::is_whitespace) {
        return false;
    }
    let Some(open) = inner.rfind('*') else {
        return false;
    };
    open + 1 < inner.len() && !inner[..open].ends_with('*')
}

/// Rule 8: the position `before.len()` lies inside a parenthesis opened right after a paper tag
/// and not closed (and not re-targeted by `ALGORITHM`) before it.
fn inside_tag_parenthesis(before: &str, tags: &[String]) -> bool {
    before.match_indices('(').any(|(i, _)| {
        let head = before[..i].trim_end();
        tag_at_end(head, tags).is_some() && {
            let seg = &before[i + 1..];
            !seg.contains(')') && !seg.contains("ALGORITHM")
        }
    })
}

/// Classifies a citation from the text before it (rules 2–8; rule 1 is handled by the caller).
fn is_external(before: &str, tags: &[String]) -> bool {
    let mut p = before.trim_end();
    while let Some(q) = p.strip_suffix(['(', '`']) {
        p = q.trim_end();
    }
    if p.ends_with("ALGORITHM") || p.ends_with("ALGORITHM.md") {
        return false;
    }
    tag_at_end(p, tags).is_some()
        || ends_with_year(p)
        || p.ends_with("et al.")
        || ends_with_other_document(p)
        || ends_with_italic_title(p)
        || inside_tag_parenthesis(before, tags)
}

/// All `§` citations of one line, classified.
fn extract(line: &str, tags: &[String]) -> Vec<Citation> {
    let mut out: Vec<Citation> = Vec::new();
    let mut prev_end: Option<usize> = None;
    let mut pos = 0;
    while let Some(off) = line[pos..].find('§') {
        let start = pos + off;
        let after = &line[start + '§'.len_utf8()..];
        let body = after.strip_prefix(' ').unwrap_or(after);
        let skipped = after.len() - body.len();
        let Some((first, n)) = parse_number(body) else {
            pos = start + '§'.len_utf8();
            continue;
        };
        let mut end = start + '§'.len_utf8() + skipped + n;
        let sections = match parse_range_end(&line[end..]) {
            Some((last, k)) => {
                end += k;
                expand_range(first, last)
            }
            None => vec![first],
        };
        let continues_list = prev_end.is_some_and(|e| {
            let gap = line[e..start].trim_matches(|c: char| c.is_whitespace() || ",/&".contains(c));
            gap.is_empty() || gap == "and" || gap == "or"
        });
        let external = match out.last() {
            Some(prev) if continues_list => prev.external,
            _ => is_external(&line[..start], tags),
        };
        out.push(Citation {
            text: line[start..end].to_string(),
            sections,
            external,
        });
        prev_end = Some(end);
        pos = end;
    }
    out
}

/// Heading numbers of a markdown text with their 1-based line numbers (fenced code skipped).
fn headings(text: &str) -> Vec<(usize, Section)> {
    let mut out = Vec::new();
    let mut in_fence = false;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim_start();
        if t.starts_with("```") || t.starts_with("~~~") {
            in_fence = !in_fence;
            continue;
        }
        if in_fence || !line.starts_with('#') {
            continue;
        }
        let rest = line.trim_start_matches('#');
        if !rest.starts_with(char::is_whitespace) {
            continue;
        }
        let rest = rest.trim_start();
        if let Some((n, k)) = parse_number(rest) {
            let tail = rest[k..].strip_prefix('.').unwrap_or(&rest[k..]);
            if tail.is_empty() || tail.starts_with(char::is_whitespace) {
                out.push((i + 1, n));
            }
        }
    }
    out
}

/// Reference keys of the "References" list: lines `* **[Key]** …`.
fn reference_keys(text: &str) -> Vec<String> {
    text.lines()
        .filter_map(|l| {
            let r = l.trim_start().strip_prefix("* **[")?;
            Some(r[..r.find("]**")?].to_string())
        })
        .collect()
}

/// For each citation of the reference in `text` whose section is not in `known`:
/// (line, section, citation text).
fn unresolved(
    text: &str,
    tags: &[String],
    known: &[Section],
) -> (usize, Vec<(usize, Section, String)>) {
    let mut checked = 0;
    let mut missing = Vec::new();
    for (i, line) in text.lines().enumerate() {
        for c in extract(line, tags) {
            if c.external {
                continue;
            }
            for s in c.sections {
                checked += 1;
                if !known.contains(&s) {
                    missing.push((i + 1, s, c.text.clone()));
                }
            }
        }
    }
    (checked, missing)
}

fn crate_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `.rs` and `.md` files under `dir`, sorted, recursively.
fn source_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    for p in paths {
        if p.is_dir() {
            source_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs" || e == "md") {
            out.push(p);
        }
    }
}

fn read_reference() -> String {
    let path = crate_root().join(REFERENCE);
    fs::read_to_string(&path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

#[test]
fn every_section_citation_resolves_to_a_heading_of_the_reference() {
    let root = crate_root();
    let reference = read_reference();
    let known: Vec<Section> = headings(&reference).into_iter().map(|(_, s)| s).collect();
    let tags = reference_keys(&reference);
    assert!(
        tags.iter().any(|t| t == "Su21") && tags.iter().any(|t| t == "Li"),
        "{REFERENCE}: the References list must define [Su21] and [Li] as `* **[Key]** …`, found {tags:?}"
    );
    let mut files = Vec::new();
    for d in SCANNED_DIRS {
        source_files(&root.join(d), &mut files);
    }
    files.retain(|p| !p.ends_with(THIS_FILE));
    files.push(root.join(REFERENCE));

    let (mut checked, mut missing) = (0, Vec::new());
    for file in &files {
        let Ok(text) = fs::read_to_string(file) else {
            continue; // not UTF-8: no comments to check
        };
        let (n, m) = unresolved(&text, &tags, &known);
        checked += n;
        let rel = file
            .strip_prefix(&root)
            .unwrap_or(file)
            .display()
            .to_string();
        missing.extend(
            m.into_iter()
                .map(|(line, s, text)| format!("{rel}:{line}: §{} (in `{text}`)", show(&s))),
        );
    }
    eprintln!(
        "citations: {checked} section numbers checked in {} files against {} headings of {REFERENCE}",
        files.len(),
        known.len()
    );
    assert!(
        checked > 100,
        "only {checked} citations found: is the extractor broken?"
    );
    assert!(
        missing.is_empty(),
        "{} citation(s) name a section that is not a heading of {REFERENCE} \
         (add the heading, fix the number, or mark a paper section with its tag, e.g. `[Su21] §n`):\n{}",
        missing.len(),
        missing.join("\n")
    );
}

#[test]
fn heading_numbers_of_the_reference_are_unique() {
    let reference = read_reference();
    let mut seen: BTreeMap<Section, Vec<usize>> = BTreeMap::new();
    for (line, s) in headings(&reference) {
        seen.entry(s).or_default().push(line);
    }
    assert!(
        seen.len() > 10,
        "{REFERENCE}: only {} numbered headings",
        seen.len()
    );
    let dups: Vec<String> = seen
        .iter()
        .filter(|(_, lines)| lines.len() > 1)
        .map(|(s, lines)| format!("§{} at lines {lines:?}", show(s)))
        .collect();
    assert!(
        dups.is_empty(),
        "{REFERENCE}: heading numbers used more than once:\n{}",
        dups.join("\n")
    );
}

// The extractor itself, on inline strings (this file is not scanned, so the bogus numbers here
// cannot fail the tree check).

fn tags() -> Vec<String> {
    vec!["Su21".to_string(), "Li".to_string()]
}

/// (section, external) of every citation of `line`.
fn cited(line: &str) -> Vec<(String, bool)> {
    extract(line, &tags())
        .into_iter()
        .flat_map(|c| c.sections.into_iter().map(move |s| (show(&s), c.external)))
        .collect()
}

fn int(s: &str) -> (String, bool) {
    (s.to_string(), false)
}

fn ext(s: &str) -> (String, bool) {
    (s.to_string(), true)
}

#[test]
fn extractor_classifies_citations() {
    // Citations of the reference.
    assert_eq!(
        cited("//! S1: particle predictors (ALGORITHM §2.4, eq. 30):"),
        [int("2.4")]
    );
    assert_eq!(cited("/// (ALGORITHM.md §1.1)."), [int("1.1")]);
    assert_eq!(cited("follows `ALGORITHM.md` §1 (\"GS4\")"), [int("1")]);
    assert_eq!(cited("(ALGORITHM §2.15, §7.2)"), [int("2.15"), int("7.2")]);
    assert_eq!(cited("//! * §1.1 — the parameters"), [int("1.1")]);
    assert_eq!(
        cited("**Deviation from ALGORITHM §2.12 (measured).** §2.12 writes"),
        [int("2.12"), int("2.12")]
    );
    assert_eq!(cited("Σᵢ mᵢ \\[Pa\\] (§2.9). Next"), [int("2.9")]);
    assert_eq!(cited("rasterised v̂ₚ, §2.5.)"), [int("2.5")]);
    assert_eq!(cited("see § 3 and §10"), [int("3"), int("10")]);
    assert_eq!(
        cited("(the \\[Li\\] \"surface particles\" source, §3.3)"),
        [int("3.3")]
    );
    assert_eq!(
        cited("\\[Li\\] (`LiViscosity`, ALGORITHM §6.2):"),
        [int("6.2")]
    );
    assert_eq!(
        cited("(§4.3, D13; \\[Li\\]'s μ₀e^{−dT}): test C1 of §9"),
        [int("4.3"), int("9")]
    );
    // Ranges.
    assert_eq!(
        cited("(ALGORITHM §2.6–2.9)"),
        [int("2.6"), int("2.7"), int("2.8"), int("2.9")]
    );
    assert_eq!(cited("//! §1.1–§1.3"), [int("1.1"), int("1.2"), int("1.3")]);
    assert_eq!(cited("§2.4/§2.13"), [int("2.4"), int("2.13")]);
    assert_eq!(cited("§2.3–3"), [int("2.3"), int("3")]);
    // Sections of other works.
    assert_eq!(
        cited("The rule printed in \\[Su21\\] §7.1.4: Δt"),
        [ext("7.1.4")]
    );
    assert_eq!(
        cited("([Su21] §7.1.3, §7.1.4)"),
        [ext("7.1.3"), ext("7.1.4")]
    );
    assert_eq!(cited("solid of \\[Li\\] §4.2 (one value"), [ext("4.2")]);
    assert_eq!(
        cited("of \\[Su21\\] (§4, eq. 14) in the form of ALGORITHM §4.2"),
        [ext("4"), int("4.2")]
    );
    assert_eq!(
        cited("\\[Li\\] (Li, Gao, He, Cheng, Li, Hao, Qin, §4.2, after"),
        [ext("4.2")]
    );
    assert_eq!(
        cited("(Stomakhin et al. 2013 §8; ALGORITHM §2.11)"),
        [ext("8"), int("2.11")]
    );
    assert_eq!(cited("Su et al. §4 and ALGORITHM §4"), [ext("4"), int("4")]);
    assert_eq!(
        cited("(Su, Xue, Han, Jiang, Aanjaneya 2021, §4.4 and"),
        [ext("4.4")]
    );
    assert_eq!(cited("(STYLE §7 item 10)"), [ext("7")]);
    assert_eq!(
        cited("(Ericson, *Real-Time Collision Detection*, §5.1.5), in f64"),
        [ext("5.1.5")]
    );
    // A section sign without a number is no citation.
    assert_eq!(cited("`§n` refers to a heading"), []);
}

#[test]
fn a_bogus_citation_is_reported_and_a_valid_one_is_not() {
    let doc = "# Title\n\n## 1 One\n\n```text\n# 7 not a heading (code)\n```\n\n### 1.2 Two\n";
    let known: Vec<Section> = headings(doc).into_iter().map(|(_, s)| s).collect();
    assert_eq!(known, [vec![1], vec![1, 2]]);
    let text =
        "// ALGORITHM §1.2 is fine\n// but §99.9 is not, nor §7\n// [Su21] §99.9 is the paper's\n";
    let (checked, missing) = unresolved(text, &tags(), &known);
    assert_eq!(checked, 3);
    assert_eq!(
        missing,
        [
            (2, vec![99, 9], "§99.9".to_string()),
            (2, vec![7], "§7".to_string())
        ]
    );
}

#[test]
fn heading_parser_reads_numbers_and_reference_keys() {
    let doc = "# treacle\n## 0 Conventions\n### 0.1 Units\n## 2. Step\n#### 7.1.2 Deep\n##2.3 no space\n## Notes 3.1\n* **[Su21]** H. Su …\n* **[Li]** C. Li …\n";
    let h: Vec<String> = headings(doc).into_iter().map(|(_, s)| show(&s)).collect();
    assert_eq!(h, ["0", "0.1", "2", "7.1.2"]);
    assert_eq!(reference_keys(doc), ["Su21", "Li"]);
}
