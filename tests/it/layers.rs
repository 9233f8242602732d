//! The layering of `src/`: dependencies between top-level modules point one way, down the
//! layers below, and nothing under the scene loader names it.
//!
//! | layer | modules |
//! |---|---|
//! | 0 math | `math`, `gs4`, `krylov` |
//! | 1 validation vocabulary | `validation` |
//! | 2 particle and grid data | `material`, `config`, `mesh`, `sampling`, `collision`, `grid`, `kernels`, `scatter`, `components`, `failure`, `output`, `spawn`, `diagnostics`, `surface`, `distributed` |
//! | 3 the step | `step` (schedule and sets, driver, one file per stage, implicit viscosity) |
//! | 4 plugins | `rheology`, `thermal`, `emit`, `rigid` |
//! | 5 composition | `plugin`, `app` |
//! | 6 scene loader | `scene` |
//! | 7 runner, reports, CLI helpers | `runner`, `report`, `snapshot`, `plot`, `render` |
//!
//! The graph is read from the code (not the comments) of every file under `src/`: a reference
//! `crate::m` (in a `use` or a path) from a file of top-level module `a` is an arrow a → m. The
//! test asserts that every top-level module is in the table, that every arrow goes to the same
//! or a lower layer, that the whole graph has no cycle (so arrows inside a layer point one way
//! too), and that only layers 6–7 name `crate::scene`. The compatibility paths `treacle::schedule`
//! and `treacle::implicit` (re-exports in `lib.rs`) are for users; the crate itself uses the
//! canonical `crate::step::…` paths, and the test refuses any name that is not a module file.
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

const LAYERS: &[(&str, &[&str])] = &[
    ("math", &["math", "gs4", "krylov", "parallel"]),
    ("validation vocabulary", &["validation"]),
    (
        "particle and grid data",
        &[
            "material",
            "config",
            "mesh",
            "sampling",
            "collision",
            "grid",
            "kernels",
            "scatter",
            "components",
            "failure",
            "output",
            "spawn",
            "diagnostics",
            "surface",
            "distributed",
        ],
    ),
    ("step", &["step"]),
    ("plugins", &["rheology", "thermal", "emit", "rigid", "game"]),
    ("composition", &["plugin", "app"]),
    ("scene loader", &["scene"]),
    (
        "runner, reports",
        &["runner", "report", "snapshot", "plot", "render"],
    ),
];

const LOADER_LAYER: usize = 6;

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|(_, ms)| ms.contains(&module))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let p = entry.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The top-level module names referenced as `crate::name` or `crate::{name, ...}` in `code`
/// (comments removed by the caller).
fn crate_refs(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let after = &rest[i + "crate::".len()..];
        let preceded_by_ident = rest[..i]
            .chars()
            .next_back()
            .is_some_and(|c| c.is_alphanumeric() || c == '_');
        if !preceded_by_ident {
            if let Some(group) = after.strip_prefix('{') {
                let end = group.find('}').unwrap_or(group.len());
                for item in group[..end].split(',') {
                    let name: String = item
                        .trim()
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_')
                        .collect();
                    if !name.is_empty() {
                        out.push(name);
                    }
                }
            } else {
                let name: String = after
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if !name.is_empty() {
                    out.push(name);
                }
            }
        }
        rest = after;
    }
    out
}

/// The code of a line: everything before a `//` that is not inside a string literal.
fn code_of(line: &str) -> &str {
    let mut in_str = false;
    let mut prev = '\0';
    for (i, c) in line.char_indices() {
        match c {
            '"' if prev != '\\' => in_str = !in_str,
            '/' if !in_str && prev == '/' => return &line[..i - 1],
            _ => {}
        }
        prev = c;
    }
    line
}

struct Graph {
    /// module → (dependency → first place it is named).
    arrows: BTreeMap<String, BTreeMap<String, String>>,
    modules: BTreeSet<String>,
}

fn read_graph() -> Graph {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut arrows: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    let mut modules = BTreeSet::new();
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy()
            .trim_end_matches(".rs")
            .to_string();
        if top == "lib" || top == "main" {
            continue;
        }
        modules.insert(top.clone());
        let text = std::fs::read_to_string(f).unwrap();
        for (n, line) in text.lines().enumerate() {
            for dep in crate_refs(code_of(line)) {
                if dep != top {
                    arrows
                        .entry(top.clone())
                        .or_default()
                        .entry(dep)
                        .or_insert_with(|| format!("src/{}:{}", rel.display(), n + 1));
                }
            }
        }
    }
    Graph { arrows, modules }
}

#[test]
fn every_module_has_a_layer() {
    let g = read_graph();
    let missing: Vec<&String> = g.modules.iter().filter(|m| layer_of(m).is_none()).collect();
    assert!(
        missing.is_empty(),
        "top-level modules not in the layer table of tests/layers.rs: {missing:?}"
    );
    let unknown: Vec<String> = g
        .arrows
        .iter()
        .flat_map(|(a, deps)| {
            deps.iter()
                .filter(|(d, _)| !g.modules.contains(*d))
                .map(move |(d, at)| format!("{at}: {a} names crate::{d}"))
        })
        .collect();
    assert!(
        unknown.is_empty(),
        "references to crate paths that are not module files (use the canonical path):\n{}",
        unknown.join("\n")
    );
}

#[test]
fn dependencies_point_down_the_layers() {
    let g = read_graph();
    let mut upward = Vec::new();
    for (a, deps) in &g.arrows {
        let (Some(la), true) = (layer_of(a), true) else {
            continue;
        };
        for (d, at) in deps {
            if let Some(ld) = layer_of(d)
                && ld > la
            {
                upward.push(format!(
                    "{at}: {a} ({}) names crate::{d} ({})",
                    LAYERS[la].0, LAYERS[ld].0
                ));
            }
        }
    }
    assert!(
        upward.is_empty(),
        "upward dependencies:\n{}",
        upward.join("\n")
    );
}

#[test]
fn no_module_below_the_loader_names_it() {
    let g = read_graph();
    let offenders: Vec<String> = g
        .arrows
        .iter()
        .filter(|(a, _)| layer_of(a).is_some_and(|l| l < LOADER_LAYER))
        .filter_map(|(a, deps)| deps.get("scene").map(|at| format!("{at}: {a}")))
        .collect();
    assert!(
        offenders.is_empty(),
        "modules below the loader naming crate::scene:\n{}",
        offenders.join("\n")
    );
}

#[test]
fn the_module_graph_has_no_cycle() {
    let g = read_graph();
    // Depth-first search with colours; reports the first cycle found as a path.
    fn visit(
        m: &str,
        g: &Graph,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(m.to_string(), 1);
        stack.push(m.to_string());
        if let Some(deps) = g.arrows.get(m) {
            for d in deps.keys() {
                match state.get(d.as_str()).copied().unwrap_or(0) {
                    0 => {
                        if let Some(c) = visit(d, g, state, stack) {
                            return Some(c);
                        }
                    }
                    1 => {
                        let from = stack.iter().position(|s| s == d).unwrap();
                        let mut cycle = stack[from..].to_vec();
                        cycle.push(d.clone());
                        return Some(cycle);
                    }
                    _ => {}
                }
            }
        }
        stack.pop();
        state.insert(m.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for m in &g.modules {
        if state.get(m.as_str()).copied().unwrap_or(0) == 0 {
            let mut stack = Vec::new();
            if let Some(cycle) = visit(m, &g, &mut state, &mut stack) {
                let places: Vec<String> = cycle
                    .windows(2)
                    .map(|w| format!("{} → {} ({})", w[0], w[1], g.arrows[&w[0]][&w[1]]))
                    .collect();
                panic!("import cycle: {}", places.join(", "));
            }
        }
    }
}

#[test]
fn the_reader_sees_what_the_checks_rely_on() {
    // The extraction itself: paths, groups, comments and strings.
    assert_eq!(crate_refs("use crate::grid::MpmGrid;"), ["grid"]);
    assert_eq!(
        crate_refs("use crate::{math::Real, step};"),
        ["math", "step"]
    );
    assert_eq!(
        crate_refs("x: crate::scene::SceneFile, y: mycrate::foo"),
        ["scene"]
    );
    assert_eq!(code_of("let a = 1; // crate::scene"), "let a = 1; ");
    assert_eq!(
        code_of(r#"let s = "http://x"; // c"#),
        r#"let s = "http://x"; "#
    );
    // An upward arrow is caught: `step` (layer 3) naming `rigid` (layer 4).
    assert!(layer_of("rigid").unwrap() > layer_of("step").unwrap());
    assert!(layer_of("scene").unwrap() == LOADER_LAYER);
}
