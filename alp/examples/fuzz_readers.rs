//! Every reader of a user's files fed mutated copies of valid ones: the
//! outcome of each must be the file read or an error naming it -- never a
//! panic, an abort (an allocation a header talked it into) or a hang.
//!
//! `cargo run --release -p alp --example fuzz_readers -- --mutants 10000 --work DIR`
//! (`--readers exr,obj` for some, `--seed N` for other mutants, `--hang-s S`,
//! `--memory-gib G` for the children's address space; `--replay PATH
//! --readers NAME` reads one kept failure in this process, its panic shown).
//!
//! The seeds are small valid files written in `DIR/seeds` (a probe folder, a
//! capture folder, a scene folder, photos in each format, JSON files, a
//! manifest). Mutant `i` of a reader is a copy of its seed with one to three
//! mutations drawn from seed `(N, reader, i)`: bit flips, bytes overwritten
//! with extreme integers (mostly in the header), truncation, ranges deleted
//! or repeated, and in text, numbers replaced by extreme ones and lines
//! dropped or repeated; in a folder, one file is mutated or deleted. Children
//! run the mutants under an address-space limit (8 GiB) and a watchdog; an
//! abort or a hang is recorded and the next child resumes after it. Failures
//! are kept in `DIR/failures/<reader>/<i>/`, the counts in `DIR/summary.json`.
//! A tool, not a test: 10,000 mutants a reader take minutes.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use alp::acquire::capture::{Capture, LEAST_VIEWS};
use alp::acquire::truth::Truth;
use alp::batch::{self, BatchOptions, Shard};
use alp::insert::MaterialSpec;
use alp::objective::Objective;
use alp::study::scenes::StudyScene;
use alp::synth::{self, CaptureSettings, SynthSettings};
use alp::{Error, Result};
use render::bsdf::GgxMetal;
use render::camera::Camera;
use render::envmap::EnvMap;
use render::error::RenderError;
use render::exif_camera::camera_from_exif;
use render::image_io::{Mask, RgbImage};
use render::mesh::Mesh;
use render::pose::Pose;
use render::probe::ProbeAsset;
use render::sampling::Rng;

/// A reader under test: its name, its seed (a file or folder under
/// `seeds/`) and the call that reads a mutant of it.
struct Reader {
    name: &'static str,
    seed: &'static str,
    read: fn(&Path) -> Result<()>,
}

const READERS: &[Reader] = &[
    Reader {
        name: "exr",
        seed: "image.exr",
        read: read_exr,
    },
    Reader {
        name: "exr_raw",
        seed: "exr/raw.exr",
        read: read_exr,
    },
    Reader {
        name: "exr_rle",
        seed: "exr/rle.exr",
        read: read_exr,
    },
    Reader {
        name: "exr_piz",
        seed: "exr/piz.exr",
        read: read_exr,
    },
    Reader {
        name: "exr_pxr24",
        seed: "exr/pxr24.exr",
        read: read_exr,
    },
    Reader {
        name: "exr_b44",
        seed: "exr/b44.exr",
        read: read_exr,
    },
    Reader {
        name: "exr_dwaa",
        seed: "exr/dwaa.exr",
        read: read_exr,
    },
    Reader {
        name: "exr_tiled",
        seed: "exr/tiled.exr",
        read: read_exr,
    },
    Reader {
        name: "envmap",
        seed: "env.exr",
        read: |p| Ok(EnvMap::read(p).map(drop)?),
    },
    Reader {
        name: "hdr",
        seed: "photo.hdr",
        read: read_photo,
    },
    Reader {
        name: "png",
        seed: "photo.png",
        read: read_photo,
    },
    Reader {
        name: "jpeg",
        seed: "photo.jpg",
        read: read_photo,
    },
    Reader {
        name: "mask",
        seed: "mask.png",
        read: |p| Ok(Mask::read_png(p).map(drop)?),
    },
    Reader {
        name: "obj",
        seed: "mesh.obj",
        read: |p| Ok(Mesh::read_obj(p).map(drop)?),
    },
    Reader {
        name: "camera",
        seed: "camera.json",
        read: |p| Ok(Camera::read(p).map(drop)?),
    },
    Reader {
        name: "pose",
        seed: "pose.json",
        read: |p| Ok(Pose::read(p).map(drop)?),
    },
    Reader {
        name: "objective",
        seed: "objective.json",
        read: |p| Objective::from_file(p).map(drop),
    },
    Reader {
        name: "material",
        seed: "material.json",
        read: |p| MaterialSpec::read(p).map(drop),
    },
    Reader {
        name: "probe",
        seed: "probe",
        read: |p| Ok(ProbeAsset::read(p).map(drop)?),
    },
    Reader {
        name: "capture",
        seed: "capture",
        read: read_capture,
    },
    Reader {
        name: "scene",
        seed: "scene",
        read: |p| StudyScene::read(p).map(drop),
    },
    Reader {
        name: "manifest",
        seed: "batch/manifest.jsonl",
        read: read_manifest,
    },
    Reader {
        name: "summaries",
        seed: "batch_out",
        read: |p| batch::merge(p).map(drop),
    },
];

fn read_exr(path: &Path) -> Result<()> {
    Ok(RgbImage::read_exr(path).map(drop)?)
}

/// A photo as `alp estimate` reads one: its pixels, then (JPEG, PNG) the
/// camera its EXIF gives, when it has one.
fn read_photo(path: &Path) -> Result<()> {
    let (image, _) = RgbImage::read_photo(path)?;
    if path.extension().is_some_and(|e| e == "jpg") {
        camera_from_exif(path, image.width as u32, image.height as u32)?;
    }
    Ok(())
}

/// A capture folder, and its truth.
fn read_capture(dir: &Path) -> Result<()> {
    Capture::read(dir)?;
    Truth::read(dir).map(drop)
}

/// A batch manifest: its lines name photos that are not there, so each
/// line fails (or is refused) without an estimate; the run must report them.
fn read_manifest(path: &Path) -> Result<()> {
    let out = path.with_file_name("out");
    let _ = std::fs::remove_dir_all(&out);
    let options = BatchOptions {
        shard: Shard::ALL,
        resume: false,
    };
    let outcomes = batch::run(path, &out, options, |_| {})?;
    match outcomes.iter().find(|o| o.status == "done") {
        Some(done) => Err(Error::invalid(
            "manifest",
            format!("line {} ran an estimate", done.line),
        )),
        None => Ok(()),
    }
}

/// How one mutant was read.
#[derive(Clone, Debug)]
enum Outcome {
    Read,
    Error,
    /// An error that does not name the mutated file or folder.
    Unnamed(String),
    Panic(String),
    Abort,
    Hang,
}

impl Outcome {
    fn kind(&self) -> &'static str {
        match self {
            Outcome::Read => "read",
            Outcome::Error => "error",
            Outcome::Unnamed(_) => "unnamed",
            Outcome::Panic(_) => "panic",
            Outcome::Abort => "abort",
            Outcome::Hang => "hang",
        }
    }

    fn message(&self) -> &str {
        match self {
            Outcome::Unnamed(m) | Outcome::Panic(m) => m,
            _ => "",
        }
    }

    fn is_failure(&self) -> bool {
        !matches!(self, Outcome::Read | Outcome::Error)
    }
}

struct Options {
    work: PathBuf,
    mutants: u64,
    seed: u64,
    readers: Vec<&'static Reader>,
    hang: Duration,
    memory_gib: u64,
    replay: Option<PathBuf>,
}

fn parse_options(args: &[String]) -> std::result::Result<(Options, Option<(u64, u64)>), String> {
    let mut options = Options {
        work: PathBuf::new(),
        mutants: 10_000,
        seed: 1,
        readers: READERS.iter().collect(),
        hang: Duration::from_secs(20),
        memory_gib: 8,
        replay: None,
    };
    let mut child = None;
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        let number = |v: &str| v.parse::<u64>().map_err(|e| format!("{flag} {v}: {e}"));
        match flag.as_str() {
            "--work" => options.work = PathBuf::from(value()?),
            "--mutants" => options.mutants = number(value()?)?,
            "--seed" => options.seed = number(value()?)?,
            "--hang-s" => options.hang = Duration::from_secs(number(value()?)?),
            "--memory-gib" => options.memory_gib = number(value()?)?,
            "--replay" => options.replay = Some(PathBuf::from(value()?)),
            "--readers" => {
                options.readers = value()?
                    .split(',')
                    .map(|name| {
                        READERS.iter().find(|r| r.name == name).ok_or_else(|| {
                            let known: Vec<_> = READERS.iter().map(|r| r.name).collect();
                            format!("unknown reader `{name}` (known: {})", known.join(", "))
                        })
                    })
                    .collect::<std::result::Result<_, _>>()?
            }
            // A child process: mutants FROM..TO of the one reader given.
            "--child" => {
                let range = value()?;
                let (from, to) = range.split_once("..").ok_or("--child FROM..TO")?;
                child = Some((number(from)?, number(to)?));
            }
            other => return Err(format!("unknown argument `{other}`")),
        }
    }
    if options.work.as_os_str().is_empty() && options.replay.is_none() {
        return Err("--work DIR is required".into());
    }
    Ok((options, child))
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (options, child) = match parse_options(&args) {
        Ok(parsed) => parsed,
        Err(e) => {
            eprintln!("fuzz_readers: {e}");
            std::process::exit(2);
        }
    };
    let result = match (child, &options.replay) {
        (Some((from, to)), _) => run_child(&options, options.readers[0], from, to),
        (None, Some(path)) => (options.readers[0].read)(path),
        (None, None) => run_parent(&options),
    };
    if let Err(e) = result {
        eprintln!("fuzz_readers: {e}");
        std::process::exit(1);
    }
}

/// Writes the seeds (once), runs every reader's mutants in children and
/// writes the summary.
fn run_parent(options: &Options) -> Result<()> {
    let seeds = options.work.join("seeds");
    if !seeds.join(".complete").is_file() {
        write_seeds(&seeds)?;
        std::fs::write(seeds.join(".complete"), "").map_err(|e| RenderError::io(&seeds, "write", e))?;
    }
    // A seed that does not read would make every mutant an error (read in a
    // copy: a reader may write beside its input).
    for reader in &options.readers {
        let copied = options.work.join("run").join(reader.name).join(reader.seed);
        let _ = std::fs::remove_dir_all(options.work.join("run").join(reader.name));
        copy(&seeds.join(reader.seed), &copied)?;
        (reader.read)(&copied).map_err(|e| Error::invalid(reader.name, format!("its seed: {e}")))?;
    }
    let mut summary = BTreeMap::new();
    println!("| reader | mutants | read | error | unnamed | panic | abort | hang | s |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for reader in &options.readers {
        let start = Instant::now();
        let outcomes = fuzz_reader(options, reader)?;
        let mut counts: BTreeMap<&str, u64> = ["read", "error", "unnamed", "panic", "abort", "hang"]
            .iter()
            .map(|&k| (k, 0))
            .collect();
        for outcome in outcomes.values() {
            *counts.entry(outcome.kind()).or_default() += 1;
        }
        let seconds = start.elapsed().as_secs_f64();
        println!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {seconds:.0} |",
            reader.name,
            outcomes.len(),
            counts["read"],
            counts["error"],
            counts["unnamed"],
            counts["panic"],
            counts["abort"],
            counts["hang"]
        );
        let mut record = serde_json::to_value(&counts).expect("counts serialise");
        record["mutants"] = outcomes.len().into();
        record["seconds"] = seconds.into();
        summary.insert(reader.name, record);
    }
    let path = options.work.join("summary.json");
    let text = serde_json::to_string_pretty(&summary).expect("summary serialises");
    std::fs::write(&path, text + "\n").map_err(|e| RenderError::io(&path, "write", e))?;
    Ok(())
}

/// Runs the mutants of `reader` in children, restarting after an abort or a
/// hang; keeps each failure's mutant and message.
fn fuzz_reader(options: &Options, reader: &Reader) -> Result<BTreeMap<u64, Outcome>> {
    let exe = std::env::current_exe().map_err(|e| RenderError::io("fuzz_readers", "find own binary", e))?;
    let mut outcomes = BTreeMap::new();
    let mut next = 0;
    while next < options.mutants {
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(format!("ulimit -v {}; exec \"$0\" \"$@\"", options.memory_gib << 20))
            .arg(&exe)
            .arg("--work")
            .arg(&options.work)
            .args(["--readers", reader.name, "--seed", &options.seed.to_string()])
            .args(["--hang-s", &options.hang.as_secs().to_string()])
            .args(["--child", &format!("{next}..{}", options.mutants)])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| RenderError::io(&exe, "start a child", e))?;
        let stdout = child.stdout.take().expect("piped stdout");
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            let Ok(record) = serde_json::from_str::<serde_json::Value>(&line) else {
                continue;
            };
            let index = record["i"].as_u64().unwrap_or(next);
            let message = record["message"].as_str().unwrap_or_default().to_string();
            let outcome = match record["kind"].as_str().unwrap_or_default() {
                "read" => Outcome::Read,
                "error" => Outcome::Error,
                "unnamed" => Outcome::Unnamed(message),
                "panic" => Outcome::Panic(message),
                "hang" => Outcome::Hang,
                _ => continue, // not a record of ours
            };
            outcomes.insert(index, outcome);
            next = index + 1;
        }
        let status = child.wait().map_err(|e| RenderError::io(&exe, "wait for a child", e))?;
        if !status.success() && status.code() != Some(HANG_EXIT) {
            // Killed (an abort) while reading mutant `next`.
            outcomes.insert(next, Outcome::Abort);
            next += 1;
        }
    }
    let failures = options.work.join("failures").join(reader.name);
    let _ = std::fs::remove_dir_all(&failures);
    for (&index, outcome) in outcomes.iter().filter(|(_, o)| o.is_failure()) {
        let kept = failures.join(index.to_string());
        write_mutant(options, reader, index, &kept)?;
        let note = kept.join("outcome.txt");
        std::fs::write(&note, format!("{}: {}\n", outcome.kind(), outcome.message()))
            .map_err(|e| RenderError::io(&note, "write", e))?;
    }
    Ok(outcomes)
}

/// When the current read began (ms since the child started; 0: none).
static READING_SINCE_MS: AtomicU64 = AtomicU64::new(0);

/// A child's exit status after its watchdog found a hang.
const HANG_EXIT: i32 = 3;

/// The last panic's message and location.
static PANIC: std::sync::Mutex<String> = std::sync::Mutex::new(String::new());

/// Reads mutants `from..to` of `reader`, one JSON line each on stdout; a
/// watchdog ends the process on a read that outlasts the hang limit.
fn run_child(options: &Options, reader: &Reader, from: u64, to: u64) -> Result<()> {
    // A panic's message and where it was raised, for the record.
    std::panic::set_hook(Box::new(|info| {
        let at = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        let message = info
            .payload()
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| info.payload().downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default();
        *PANIC.lock().unwrap_or_else(|e| e.into_inner()) = format!("{message}{at}");
    }));
    let clock = Instant::now();
    let current = std::sync::Arc::new(AtomicU64::new(from));
    let hang_ms = options.hang.as_millis() as u64;
    let watched = current.clone();
    std::thread::spawn(move || {
        loop {
            std::thread::sleep(Duration::from_millis(100));
            let since = READING_SINCE_MS.load(Ordering::SeqCst);
            if since > 0 && clock.elapsed().as_millis() as u64 - since > hang_ms {
                let i = watched.load(Ordering::SeqCst);
                println!("{}", serde_json::json!({"i": i, "kind": "hang"}));
                std::process::exit(HANG_EXIT);
            }
        }
    });
    let dir = options.work.join("run").join(reader.name);
    let stdout = std::io::stdout();
    for index in from..to {
        current.store(index, Ordering::SeqCst);
        let _ = std::fs::remove_dir_all(&dir);
        let mutant = write_mutant(options, reader, index, &dir)?;
        READING_SINCE_MS.store((clock.elapsed().as_millis() as u64).max(1), Ordering::SeqCst);
        let read = catch_unwind(AssertUnwindSafe(|| (reader.read)(&mutant)));
        READING_SINCE_MS.store(0, Ordering::SeqCst);
        let outcome = match read {
            Ok(Ok(())) => Outcome::Read,
            Ok(Err(e)) => {
                let message = e.to_string();
                if message.contains(&*mutant.to_string_lossy()) {
                    Outcome::Error
                } else {
                    Outcome::Unnamed(message)
                }
            }
            Err(_) => Outcome::Panic(std::mem::take(&mut *PANIC.lock().unwrap_or_else(|e| e.into_inner()))),
        };
        let line = serde_json::json!({"i": index, "kind": outcome.kind(), "message": outcome.message()});
        let mut lock = stdout.lock();
        let _ = writeln!(lock, "{line}");
        let _ = lock.flush();
    }
    Ok(())
}

/// Writes mutant `index` of `reader` into `dir`; returns the path to read.
fn write_mutant(options: &Options, reader: &Reader, index: u64, dir: &Path) -> Result<PathBuf> {
    let seed = options.work.join("seeds").join(reader.seed);
    let name = seed.file_name().expect("seeds have names");
    let target = dir.join(name);
    copy(&seed, &target)?;
    let salt = reader
        .name
        .bytes()
        .fold(0u64, |h, b| h.wrapping_mul(31).wrapping_add(b as u64));
    let mut rng = Rng::new(options.seed ^ salt.rotate_left(32), index);
    let file = if target.is_dir() {
        let mut files = Vec::new();
        list_files(&target, &mut files)?;
        files.sort();
        let file = files[rng.next_below(files.len() as u32) as usize].clone();
        if rng.next_below(10) == 0 {
            std::fs::remove_file(&file).map_err(|e| RenderError::io(&file, "delete", e))?;
            return Ok(target);
        }
        file
    } else {
        target.clone()
    };
    let mut bytes = std::fs::read(&file).map_err(|e| RenderError::io(&file, "read", e))?;
    for _ in 0..1 + rng.next_below(3) {
        mutate(&mut bytes, &mut rng);
    }
    std::fs::write(&file, bytes).map_err(|e| RenderError::io(&file, "write", e))?;
    Ok(target)
}

/// Copies file or folder `from` to `to`.
fn copy(from: &Path, to: &Path) -> Result<()> {
    if from.is_dir() {
        std::fs::create_dir_all(to).map_err(|e| RenderError::io(to, "create", e))?;
        let entries = std::fs::read_dir(from).map_err(|e| RenderError::io(from, "list", e))?;
        for entry in entries {
            let entry = entry.map_err(|e| RenderError::io(from, "list", e))?;
            copy(&entry.path(), &to.join(entry.file_name()))?;
        }
        return Ok(());
    }
    if let Some(parent) = to.parent() {
        std::fs::create_dir_all(parent).map_err(|e| RenderError::io(parent, "create", e))?;
    }
    std::fs::copy(from, to).map_err(|e| RenderError::io(from, "copy", e))?;
    Ok(())
}

fn list_files(dir: &Path, files: &mut Vec<PathBuf>) -> Result<()> {
    let entries = std::fs::read_dir(dir).map_err(|e| RenderError::io(dir, "list", e))?;
    for entry in entries {
        let path = entry.map_err(|e| RenderError::io(dir, "list", e))?.path();
        if path.is_dir() {
            list_files(&path, files)?;
        } else {
            files.push(path);
        }
    }
    Ok(())
}

/// Integers a header is talked into: signs, powers of two, limits.
const EXTREME_INTEGERS: [u32; 10] = [
    0,
    1,
    0x7f,
    0xff,
    0xffff,
    1 << 20,
    1 << 30,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
];

/// Numbers a text field is talked into.
const EXTREME_NUMBERS: [&str; 12] = [
    "0",
    "-1",
    "-0",
    "1e300",
    "-1e300",
    "1e-300",
    "NaN",
    "inf",
    "4294967297",
    "99999999999999999999",
    "0.5",
    "",
];

/// One mutation of `bytes`: text ones when it reads as text, half the time.
fn mutate(bytes: &mut Vec<u8>, rng: &mut Rng) {
    let is_text = !bytes.is_empty() && std::str::from_utf8(bytes).is_ok_and(|t| !t.contains('\0'));
    if is_text && rng.next_below(2) == 0 {
        mutate_text(bytes, rng);
        return;
    }
    let len = bytes.len() as u32;
    // Most mutations land in the first 512 bytes, where the headers are.
    let at = |rng: &mut Rng| {
        let span = if rng.next_below(10) < 6 { len.min(512) } else { len };
        rng.next_below(span.max(1)) as usize
    };
    match if bytes.is_empty() { 6 } else { rng.next_below(7) } {
        0 => {
            for _ in 0..1 + rng.next_below(8) {
                let i = at(rng);
                bytes[i] ^= 1 << rng.next_below(8);
            }
        }
        1 => {
            for _ in 0..1 + rng.next_below(4) {
                let i = at(rng);
                bytes[i] = rng.next_u32() as u8;
            }
        }
        2 => {
            let value = EXTREME_INTEGERS[rng.next_below(EXTREME_INTEGERS.len() as u32) as usize];
            let i = at(rng);
            let end = (i + 4).min(bytes.len());
            bytes[i..end].copy_from_slice(&value.to_le_bytes()[..end - i]);
        }
        3 => bytes.truncate(rng.next_below(len) as usize),
        4 => {
            let i = at(rng);
            let end = (i + 1 + rng.next_below(64) as usize).min(bytes.len());
            bytes.drain(i..end);
        }
        5 => {
            let i = at(rng);
            let end = (i + 1 + rng.next_below(64) as usize).min(bytes.len());
            let copy = bytes[i..end].to_vec();
            let to = at(rng);
            bytes.splice(to..to, copy);
        }
        _ => {
            let to = if bytes.is_empty() { 0 } else { at(rng) };
            let insert: Vec<u8> = (0..1 + rng.next_below(16)).map(|_| rng.next_u32() as u8).collect();
            bytes.splice(to..to, insert);
        }
    }
}

/// One mutation of a text file: a number made extreme, a line dropped,
/// repeated or swapped, or a character replaced by punctuation.
fn mutate_text(bytes: &mut Vec<u8>, rng: &mut Rng) {
    let text = String::from_utf8(std::mem::take(bytes)).expect("checked UTF-8");
    let mut lines: Vec<&str> = text.split_inclusive('\n').collect();
    let pick = |rng: &mut Rng, n: usize| rng.next_below(n as u32) as usize;
    let mutated = match rng.next_below(5) {
        0 => {
            let numbers = number_spans(&text);
            if numbers.is_empty() {
                text.clone()
            } else {
                let (start, end) = numbers[pick(rng, numbers.len())];
                let number = EXTREME_NUMBERS[pick(rng, EXTREME_NUMBERS.len())];
                format!("{}{number}{}", &text[..start], &text[end..])
            }
        }
        1 => {
            lines.remove(pick(rng, lines.len()));
            lines.concat()
        }
        2 => {
            let i = pick(rng, lines.len());
            lines.insert(i, lines[i]);
            lines.concat()
        }
        3 => {
            let (i, j) = (pick(rng, lines.len()), pick(rng, lines.len()));
            lines.swap(i, j);
            lines.concat()
        }
        _ => {
            let mut chars: Vec<char> = text.chars().collect();
            let i = pick(rng, chars.len());
            chars[i] = ['{', '}', '[', ']', '"', ',', ':', '/', '\\', '\n', ' ', '-'][pick(rng, 12)];
            chars.into_iter().collect()
        }
    };
    *bytes = mutated.into_bytes();
}

/// Byte spans of the numbers in `text` (runs of digits, signs, points and
/// exponents holding a digit).
fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let is_part = |c: u8| c.is_ascii_digit() || matches!(c, b'.' | b'-' | b'+' | b'e' | b'E');
    let bytes = text.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i].is_ascii_digit()
            || (matches!(bytes[i], b'-' | b'.') && bytes.get(i + 1).is_some_and(u8::is_ascii_digit))
        {
            let start = i;
            while i < bytes.len() && is_part(bytes[i]) {
                i += 1;
            }
            spans.push((start, i));
        } else {
            i += 1;
        }
    }
    spans
}

/// Writes the seeds: small valid files of every kind the readers take.
fn write_seeds(seeds: &Path) -> Result<()> {
    let _ = std::fs::remove_dir_all(seeds);
    std::fs::create_dir_all(seeds).map_err(|e| RenderError::io(seeds, "create", e))?;
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
    let env = EnvMap::read(assets.join("envmaps/studio.exr"))?.downsample(16);
    env.write(seeds.join("env.exr"))?;
    let probe = alp::probes::procedural("can")?;
    probe.write(seeds.join("probe"))?;
    probe.mesh.write_obj(seeds.join("mesh.obj"))?;
    let capture = synth::synthesize_capture(
        &probe,
        &env,
        &GgxMetal,
        &CaptureSettings {
            views: LEAST_VIEWS,
            spp: 2,
            width: 40,
            height: 30,
            ..CaptureSettings::default()
        },
    )?;
    synth::write_capture(&seeds.join("capture"), &capture)?;
    let scene = synth::synthesize(
        &probe,
        &env,
        &SynthSettings {
            spp: 2,
            width: 48,
            height: 36,
            ..SynthSettings::default()
        },
    )?;
    let probe_dir = std::fs::canonicalize(seeds.join("probe")).map_err(|e| RenderError::io(seeds, "resolve", e))?;
    synth::write_scene(&seeds.join("scene"), &scene, &env, &probe_dir.to_string_lossy())?;
    scene.image.write_exr(seeds.join("image.exr"))?;
    scene.mask.write_png(seeds.join("mask.png"))?;
    scene.camera.write(seeds.join("camera.json"))?;
    scene.pose.write(seeds.join("pose.json"))?;
    write_photos(seeds, &scene.image)?;
    write_exr_seeds(&seeds.join("exr"), &scene.image)?;
    let copy_asset = |from: &str, to: &str| copy(&assets.join(from), &seeds.join(to));
    copy_asset("objectives/paper_default.json", "objective.json")?;
    let text_seeds = [
        (
            "material.json",
            "{\"type\": \"metal\", \"albedo\": [0.9, 0.6, 0.3], \"roughness\": 0.2}\n".to_string(),
        ),
        (
            "batch/manifest.jsonl",
            [
                r#"{"id": "a", "image": "a.exr", "mask": "a.png", "camera": "a.json", "probe": "can"}"#,
                r#"{"id": "b", "image": "b.jpg", "box": "10,12,40,30", "probe": "can", "quality": "fast", "seed": 3}"#,
                r#"{"id": "c", "image": "c.hdr", "mask": "box", "probe": "cap", "env_size": "32x16"}"#,
            ]
            .join("\n")
                + "\n",
        ),
    ];
    for (name, text) in text_seeds {
        let path = seeds.join(name);
        std::fs::create_dir_all(path.parent().expect("a folder")).map_err(|e| RenderError::io(&path, "create", e))?;
        std::fs::write(&path, text).map_err(|e| RenderError::io(&path, "write", e))?;
    }
    // Two shards' summaries of the manifest (its photos missing), one with a finished photo.
    let out = seeds.join("batch_out");
    for index in 0..2 {
        let options = BatchOptions {
            shard: Shard { index, count: 2 },
            resume: false,
        };
        batch::run(&seeds.join("batch/manifest.jsonl"), &out, options, |_| {})?;
    }
    let done = r#"{"id": "d", "line": 4, "status": "done", "error": null, "wall_s": 31.5, "psnr_db": 27.1}"#;
    let shard = out.join(Shard { index: 1, count: 2 }.summary_name());
    let text = std::fs::read_to_string(&shard).map_err(|e| RenderError::io(&shard, "read", e))? + done + "\n";
    std::fs::write(&shard, text).map_err(|e| RenderError::io(&shard, "write", e))?;
    Ok(())
}

/// The scene's photo as Radiance HDR, 8-bit PNG and a JPEG with EXIF.
fn write_photos(seeds: &Path, image: &RgbImage) -> Result<()> {
    let (w, h) = (image.width as u32, image.height as u32);
    let hdr_path = seeds.join("photo.hdr");
    let linear = image::Rgb32FImage::from_fn(w, h, |x, y| image::Rgb(image.get(y as usize, x as usize)));
    linear
        .save(&hdr_path)
        .map_err(|e| RenderError::io(&hdr_path, "write", e))?;
    let png_path = seeds.join("photo.png");
    image.write_png_preview(&png_path, 0.0)?;
    let jpeg_path = seeds.join("photo.jpg");
    let srgb = image::open(&png_path)
        .map_err(|e| RenderError::io(&png_path, "read", e))?
        .into_rgb8();
    let mut jpeg = Vec::new();
    srgb.write_to(&mut std::io::Cursor::new(&mut jpeg), image::ImageFormat::Jpeg)
        .map_err(|e| RenderError::io(&jpeg_path, "encode", e))?;
    // An APP1 segment after the start of image: EXIF with a 26 mm 35 mm-equivalent focal length.
    let mut tiff = b"II\x2a\x00\x08\x00\x00\x00".to_vec();
    tiff.extend([1, 0, 0x69, 0x87, 4, 0, 1, 0, 0, 0, 26, 0, 0, 0, 0, 0, 0, 0]); // IFD0: Exif IFD at 26
    tiff.extend([1, 0, 0x05, 0xa4, 3, 0, 1, 0, 0, 0, 26, 0, 0, 0, 0, 0, 0, 0]); // FocalLengthIn35mmFilm
    let mut app1 = b"Exif\0\0".to_vec();
    app1.extend(tiff);
    let mut out = jpeg[..2].to_vec();
    out.extend([0xff, 0xe1]);
    out.extend(((app1.len() + 2) as u16).to_be_bytes());
    out.extend(app1);
    out.extend(&jpeg[2..]);
    std::fs::write(&jpeg_path, out).map_err(|e| RenderError::io(&jpeg_path, "write", e))?;
    let check = camera_from_exif(&jpeg_path, w, h)?;
    assert!(check.fov_y_deg > 1.0, "the seed JPEG's EXIF gives a camera");
    Ok(())
}

/// `image` as OpenEXR in each compression (f16 where the codec is made for
/// it), and tiled: files from other writers than ours.
fn write_exr_seeds(dir: &Path, image: &RgbImage) -> Result<()> {
    use exr::prelude::{
        Blocks, Compression, Encoding, Image, Layer, LayerAttributes, LineOrder, SpecificChannels, WritableImage, f16,
    };
    std::fs::create_dir_all(dir).map_err(|e| RenderError::io(dir, "create", e))?;
    let scan_lines = |compression| Encoding {
        compression,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let tiles = Encoding {
        compression: Compression::ZIP16,
        blocks: Blocks::Tiles(exr::math::Vec2(16, 16)),
        line_order: LineOrder::Increasing,
    };
    let size = (image.width, image.height);
    let pixel = |x: usize, y: usize| image.get(y, x);
    for (name, encoding, half) in [
        ("raw", scan_lines(Compression::Uncompressed), false),
        ("rle", scan_lines(Compression::RLE), true),
        ("piz", scan_lines(Compression::PIZ), true),
        ("pxr24", scan_lines(Compression::PXR24), false),
        ("b44", scan_lines(Compression::B44), true),
        ("dwaa", scan_lines(Compression::DWAA(None)), true),
        ("tiled", tiles, true),
    ] {
        let path = dir.join(format!("{name}.exr"));
        let attributes = LayerAttributes::named("photo");
        let written = if half {
            let channels = SpecificChannels::rgb(|exr::math::Vec2(x, y)| {
                let [r, g, b] = pixel(x, y).map(f16::from_f32);
                (r, g, b)
            });
            Image::from_layer(Layer::new(size, attributes, encoding, channels))
                .write()
                .to_file(&path)
        } else {
            let channels = SpecificChannels::rgb(|exr::math::Vec2(x, y)| {
                let [r, g, b] = pixel(x, y);
                (r, g, b)
            });
            Image::from_layer(Layer::new(size, attributes, encoding, channels))
                .write()
                .to_file(&path)
        };
        written.map_err(|e| RenderError::io(&path, "write OpenEXR", e))?;
    }
    Ok(())
}
