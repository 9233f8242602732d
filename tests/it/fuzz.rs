//! A deterministic mutation fuzz of the shipped scenes: deletions, extreme numbers, renamed
//! fields, truncation, random bytes, duplicated and swapped lines, deep nesting. For every
//! mutant the loader must either accept it or refuse it with an error that names the file, a
//! line and a field (`Scene` for the scene value as a whole); an accepted mutant runs three steps, which
//! must end normally, with a numerical-failure diagnostic or with a memory refusal. No panic,
//! no abort, no hang (a watchdog aborts the test with the mutant's seed if one takes longer
//! than [`HANG_SECONDS`]).
//!
//! The suite runs [`CI_MUTANTS`] mutants; `TREACLE_FUZZ_MUTANTS=3000 cargo test --release
//! --test it fuzz -- --nocapture` runs more (seed: `TREACLE_FUZZ_SEED`, default 14).
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::common::{crate_dir, scratch};
use treacle::runner::{RunError, bench_scene};
use treacle::scene::{SceneError, load_scene, parse_scene_str};

/// Mutants in the test suite (20–40 s on a 2-core machine).
const CI_MUTANTS: u64 = 3000;

/// A mutant whose load and three steps take longer than this is a hang.
const HANG_SECONDS: u64 = 120;

/// Largest accepted mutant that is also run (particles, grid nodes): bigger ones are only
/// loaded, so that the fuzz stays within its minute.
const RUN_LIMIT: (u64, u64) = (60_000, 3_000_000);

/// SplitMix64: a small deterministic generator (no dependency).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const EXTREMES: [&str; 16] = [
    "0",
    "0.0",
    "-1.0",
    "1e-40",
    "1e-30",
    "1e-9",
    "1e9",
    "1e15",
    "1e30",
    "3e38",
    "1e308",
    "-1e308",
    "inf",
    "-inf",
    "NaN",
    "4294967296",
];

/// Byte ranges of the numbers in `text` (outside comments and strings, roughly: digits with
/// an optional sign, point and exponent, not part of an identifier).
fn numbers(text: &str) -> Vec<(usize, usize)> {
    let b = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    let mut in_comment = false;
    while i < b.len() {
        if in_comment {
            if b[i] == b'\n' {
                in_comment = false;
            }
            i += 1;
            continue;
        }
        if b[i] == b'/' && b.get(i + 1) == Some(&b'/') {
            in_comment = true;
            i += 2;
            continue;
        }
        let starts =
            b[i].is_ascii_digit() || (b[i] == b'-' && b.get(i + 1).is_some_and(u8::is_ascii_digit));
        let after_ident = i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_');
        if starts && !after_ident {
            let s = i;
            i += 1;
            while i < b.len() && (b[i].is_ascii_digit() || matches!(b[i], b'.' | b'e' | b'E')) {
                i += 1;
            }
            out.push((s, i));
        } else {
            i += 1;
        }
    }
    out
}

/// One mutation of `text`; returns the mutant and what was done.
fn mutate(text: &str, rng: &mut Rng) -> (Vec<u8>, String) {
    let lines: Vec<&str> = text.lines().collect();
    match rng.below(8) {
        0 => {
            let k = rng.below(lines.len());
            let mut l = lines.clone();
            l.remove(k);
            (l.join("\n").into_bytes(), format!("delete line {}", k + 1))
        }
        1 | 2 => {
            let nums = numbers(text);
            if nums.is_empty() {
                return (text.as_bytes().to_vec(), "unchanged".into());
            }
            let (s, e) = nums[rng.below(nums.len())];
            let v = EXTREMES[rng.below(EXTREMES.len())];
            let mut out = String::from(&text[..s]);
            out.push_str(v);
            out.push_str(&text[e..]);
            (out.into_bytes(), format!("number `{}` → {v}", &text[s..e]))
        }
        3 => {
            // Rename a field: change one letter of an identifier followed by `:`.
            let fields: Vec<usize> = text
                .match_indices(':')
                .map(|(i, _)| i)
                .filter(|&i| i > 0 && text.as_bytes()[i - 1].is_ascii_alphabetic())
                .collect();
            if fields.is_empty() {
                return (text.as_bytes().to_vec(), "unchanged".into());
            }
            let i = fields[rng.below(fields.len())] - 1;
            let mut b = text.as_bytes().to_vec();
            b[i] = if b[i] == b'q' { b'z' } else { b'q' };
            (b, format!("rename the field ending at byte {i}"))
        }
        4 => {
            let cut = rng.below(text.len());
            (
                text.as_bytes()[..cut].to_vec(),
                format!("truncate at byte {cut}"),
            )
        }
        5 => {
            let at = rng.below(text.len());
            let n = 1 + rng.below(16);
            let mut b = text.as_bytes().to_vec();
            for _ in 0..n {
                b.insert(at, rng.next() as u8);
            }
            (b, format!("{n} random bytes at byte {at}"))
        }
        6 => {
            let (a, c) = (rng.below(lines.len()), rng.below(lines.len()));
            let mut l = lines.clone();
            if rng.below(2) == 0 {
                l.insert(c, lines[a]);
                (
                    l.join("\n").into_bytes(),
                    format!("duplicate line {}", a + 1),
                )
            } else {
                l.swap(a, c);
                (
                    l.join("\n").into_bytes(),
                    format!("swap lines {} and {}", a + 1, c + 1),
                )
            }
        }
        _ => {
            // Deep nesting around a number.
            let nums = numbers(text);
            let depth = [10, 100, 10_000, 100_000][rng.below(4)];
            let (s, e) = nums.get(rng.below(nums.len())).copied().unwrap_or((0, 0));
            let mut out = String::from(&text[..s]);
            out.push_str(&"[".repeat(depth));
            out.push_str(&text[s..e]);
            out.push_str(&"]".repeat(depth));
            out.push_str(&text[e..]);
            (out.into_bytes(), format!("nest a number {depth} deep"))
        }
    }
}

/// What one mutant did.
#[derive(Debug, Default)]
struct Tally {
    refused: u64,
    accepted: u64,
    ran: u64,
    numerical_failures: u64,
    memory_refusals: u64,
}

/// Loads `bytes` as the scene `path` (relative assets from `dir`) and, if accepted and small,
/// runs three steps. Errors that break the contract are returned as text.
fn check_mutant(bytes: &[u8], path: &Path, dir: &Path, tally: &mut Tally) -> Result<(), String> {
    let loaded = match std::str::from_utf8(bytes) {
        Ok(text) => parse_scene_str(text, path, dir),
        // Not UTF-8: through the file loader, which decodes and locates the bad byte.
        Err(_) => {
            let file = scratch("not-utf8").join(path);
            std::fs::write(&file, bytes).unwrap();
            let loaded = load_scene(&file);
            assert!(loaded.is_err(), "invalid UTF-8 was accepted");
            return check_refusal(loaded.err().unwrap(), &file, tally);
        }
    };
    match loaded {
        Err(e) => check_refusal(e, path, tally),
        Ok(scene) => {
            tally.accepted += 1;
            let est = scene.resource_estimate();
            if est.particles() > RUN_LIMIT.0 || est.grid_nodes > RUN_LIMIT.1 {
                return Ok(());
            }
            tally.ran += 1;
            match bench_scene(scene.clone(), 3) {
                Ok(_) => Ok(()),
                Err(RunError::Failed(_)) => {
                    tally.numerical_failures += 1;
                    Ok(())
                }
                Err(RunError::TooLarge(_)) => {
                    tally.memory_refusals += 1;
                    Ok(())
                }
                Err(other) => Err(format!("the run ended with {other}")),
            }
        }
    }
}

/// A refusal must name the file, a line and a field for every error.
fn check_refusal(e: SceneError, path: &Path, tally: &mut Tally) -> Result<(), String> {
    tally.refused += 1;
    let errors = e.errors();
    if errors.is_empty() {
        return Err(format!("an error without a location: {e}"));
    }
    for f in errors {
        if f.file != path || f.line == 0 {
            return Err(format!("an error without file and line: {f}"));
        }
    }
    if errors.iter().any(|f| f.field.is_empty()) {
        return Err(format!("an error without a field: {e}"));
    }
    Ok(())
}

/// The shipped scenes (text, path).
fn shipped() -> Vec<(String, PathBuf)> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(crate_dir().join("scenes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ron"))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|p| (std::fs::read_to_string(&p).unwrap(), p))
        .collect()
}

#[test]
fn mutated_scenes_never_panic_abort_or_hang() {
    let count: u64 = std::env::var("TREACLE_FUZZ_MUTANTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(CI_MUTANTS);
    let seed: u64 = std::env::var("TREACLE_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(14);
    let scenes = shipped();
    let dir = crate_dir().join("scenes");
    // Watchdog: the index of the running mutant and when it started.
    let current = Arc::new(AtomicU64::new(u64::MAX));
    let started = Arc::new(AtomicU64::new(0));
    let t0 = Instant::now();
    {
        let (current, started) = (current.clone(), started.clone());
        std::thread::spawn(move || {
            loop {
                std::thread::sleep(Duration::from_secs(1));
                let k = current.load(Ordering::SeqCst);
                let since = t0.elapsed().as_secs() - started.load(Ordering::SeqCst);
                if k != u64::MAX && since > HANG_SECONDS {
                    eprintln!("mutant {k} (seed {seed}) runs for over {HANG_SECONDS} s: a hang");
                    std::process::abort();
                }
            }
        });
    }
    let mut tally = Tally::default();
    let mut broken = Vec::new();
    for k in 0..count {
        let mut rng = Rng(seed.wrapping_mul(0x1000_0000_01B3) ^ k);
        let (text, path) = &scenes[rng.below(scenes.len())];
        let (bytes, what) = mutate(text, &mut rng);
        started.store(t0.elapsed().as_secs(), Ordering::SeqCst);
        current.store(k, Ordering::SeqCst);
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if std::env::var_os("TREACLE_FUZZ_TRACE").is_some() {
            eprintln!("mutant {k} of {name}: {what}");
        }
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            check_mutant(&bytes, Path::new(&name), &dir, &mut tally)
        }));
        let problem = match result {
            Ok(Ok(())) => continue,
            Ok(Err(e)) => e,
            Err(_) => "panicked".to_string(),
        };
        broken.push(format!("mutant {k} of {name} ({what}): {problem}"));
    }
    current.store(u64::MAX, Ordering::SeqCst);
    println!(
        "{count} mutants (seed {seed}) in {:.1} s: {tally:?}; {} broke the contract",
        t0.elapsed().as_secs_f64(),
        broken.len()
    );
    assert!(broken.is_empty(), "{}", broken.join("\n"));
    assert!(tally.refused > 0 && tally.accepted > 0, "{tally:?}");
}
