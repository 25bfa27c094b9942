//! The one writer and the one way to open an input: every file `jdbb` writes goes through here,
//! and every input file is opened with [`open_input`] (size limits, special files).
//!
//! # Writing
//! - **Destinations.** A destination is nothing yet, or a regular file that is replaced only when
//!   the user says `--force` ([`Error::OutputExists`] names `--force` otherwise). A symbolic link,
//!   a directory (where a file is meant), a device (`/dev/null`, `/dev/full`), a pipe or a socket
//!   is refused whatever `--force` says ([`Error::OutputNotAFile`]): the program never writes
//!   through a link nor replaces a device node ([`check_destination`]).
//! - **Whole files.** A file is written to a temporary file in the destination's directory
//!   (created new, never an existing file), flushed, `fsync`ed, then renamed over the
//!   destination, so a reader finds the old file or the new one, never half of one. Without
//!   `--force` the temporary file is hard-linked into place, so a file that appeared meanwhile is
//!   not replaced either ([`Staged`], [`write_file`], [`write_via`]).
//! - **Sets.** Files that belong together (plan.json and its program, a controller's
//!   compensation files) are all staged before any is put in place; a failure while putting them
//!   in place puts the old ones back ([`FileSet`]). A report directory is built whole beside the
//!   destination and swapped in ([`write_dir`]), so it never mixes new and stale files; its
//!   [`DIR_MARK`] lists what it wrote, and a directory holding anything else is not replaced.
//! - **Inputs.** An output is never one of the command's inputs ([`check_not_input`]: the same
//!   file by any name, or an input inside an output directory), even with `--force`.
//! - **Interruption.** Temporary files and directories are registered while they exist;
//!   [`exit_on_interrupt`] makes Ctrl-C (SIGTERM, SIGHUP) remove them and exit 130 at once, so an
//!   interrupted command leaves no partial output. Whatever is put in place is put there under
//!   the same lock, which the handler takes and keeps: a set is finished before the process ends
//!   (old or new, never a mix), and the message says whether an output was written. Temporary
//!   files of a process that no longer runs (SIGKILL) are removed by the next write beside them,
//!   and a set it was putting in place is rolled back from its journal by the next set there;
//!   a write past the file size limit is an error, not a SIGXFSZ death
//!   ([`fail_writes_past_size_limit`]).
//!
//! # Reading
//! [`open_input`] opens an input file for reading without waiting at the opening (a named pipe
//! with no writer reads as empty): a directory is refused, and the bytes read are
//! limited ([`LimitedReader`]): past the limit, reading fails with a message that names the limit
//! (exit 2). The limits per kind of input are [`Limit`]; `/dev/zero` or a runaway file is stopped
//! there instead of filling the memory.
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};

use crate::{Error, Result};

/// Temporary files and directories that exist now (removed on an interrupt). Whatever is put in
/// place (a rename, a set swapped in) is put there with this lock held, and the interrupt handler
/// takes it and keeps it until the process ends: an interrupt waits for a set being put in place
/// and then nothing more is.
static STAGED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// How many outputs this process has put in place (what an interrupt's message says).
static PLACED: AtomicUsize = AtomicUsize::new(0);

fn staged() -> MutexGuard<'static, Vec<PathBuf>> {
    STAGED.lock().unwrap_or_else(PoisonError::into_inner)
}

fn unregister(p: &Path) {
    staged().retain(|q| q != p);
}

fn remove_all(v: &mut Vec<PathBuf>) {
    for p in v.drain(..) {
        if fs::symlink_metadata(&p).is_ok_and(|m| m.is_dir()) {
            let _ = fs::remove_dir_all(&p);
        } else {
            let _ = fs::remove_file(&p);
        }
    }
}

/// Count `n` outputs put at `dest` (a file inside a staging directory is not an output yet).
fn count_placed(v: &[PathBuf], dest: &Path, n: usize) {
    if !v.iter().any(|s| dest.starts_with(s)) {
        PLACED.fetch_add(n, Ordering::SeqCst);
    }
}

/// Remove every temporary file and directory this process has staged and not yet put in place.
pub fn remove_staged() {
    remove_all(&mut staged());
}

/// What an interrupt leaves, in words, when `placed` outputs had been put in place.
fn interrupted_message(placed: usize) -> String {
    match placed {
        0 => "interrupted; no output was written (what was in place before is as it was)".into(),
        n => format!(
            "interrupted after {n} output file(s) or set(s) had been written whole; nothing half-written was left (the others are as they were)"
        ),
    }
}

/// Make Ctrl-C (and SIGTERM, SIGHUP) end the process within milliseconds with exit code 130,
/// after removing what it staged ([`remove_staged`]): for every command but those that
/// talk to a device (`record`, `live`, `calibration`), which end their session themselves. A rename
/// or a set being put in place finishes first (it holds the same lock), so an output or a set is
/// whole or as it was, and the message says which.
pub fn exit_on_interrupt() {
    // A second handler cannot be installed (a command that has its own, such as `record`,
    // keeps it); that is not an error here.
    let _ = ctrlc::set_handler(|| {
        // Held until the process ends: nothing is put in place after this.
        let mut v = staged();
        remove_all(&mut v);
        let _ = writeln!(
            io::stderr(),
            "{}",
            interrupted_message(PLACED.load(Ordering::SeqCst))
        );
        std::process::exit(130);
    });
}

/// Make a write beyond the process's file size limit (`ulimit -f`) fail with an error (EFBIG:
/// "File too large", then the output is as it was) instead of killing the process silently with
/// SIGXFSZ and leaving its temporary files behind.
pub fn fail_writes_past_size_limit() {
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to "ignore" (no handler code runs).
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

/// What `path` is, in words, if it is not a regular file (None: a regular file).
fn not_a_file(meta: &fs::Metadata) -> Option<&'static str> {
    let t = meta.file_type();
    if t.is_symlink() {
        Some("a symbolic link")
    } else if t.is_dir() {
        Some("a directory")
    } else if !t.is_file() {
        Some("a device, pipe or socket")
    } else {
        None
    }
}

/// Check that a file may be written at `path`: nothing there, or (with `force`) a regular file
/// to be replaced. A symbolic link, a directory, a device (`/dev/null`), a pipe or a socket is
/// refused whatever `force` says. Touches nothing.
pub fn check_destination(path: &Path, force: bool) -> Result<()> {
    let meta = match fs::symlink_metadata(path) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
        Err(source) => {
            return Err(Error::File {
                action: "cannot check",
                path: path.to_path_buf(),
                source,
            })
        }
        Ok(m) => m,
    };
    match not_a_file(&meta) {
        Some(what) => Err(Error::OutputNotAFile {
            path: path.to_path_buf(),
            what,
        }),
        None if force => Ok(()),
        None => Err(Error::OutputExists {
            path: path.to_path_buf(),
        }),
    }
}

/// The directory `path` is in (`.` for a bare name).
fn parent_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned())
}

/// A new temporary path beside `dest`: `.NAME.jdbb-PID-N.tmp` (N counts up).
fn temp_name(dest: &Path, n: u32) -> PathBuf {
    parent_of(dest).join(format!(
        ".{}.jdbb-{}-{n}.tmp",
        file_name(dest),
        std::process::id()
    ))
}

/// Whether the process `pid` is alive (or may be: one of another user's).
fn alive(pid: u32) -> bool {
    #[cfg(unix)]
    {
        let Ok(pid) = libc::pid_t::try_from(pid) else {
            return true;
        };
        // SAFETY: signal 0 sends nothing; it only asks whether the process exists.
        let r = unsafe { libc::kill(pid, 0) };
        r == 0 || io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
    }
    #[cfg(not(unix))]
    {
        let _ = pid;
        true
    }
}

/// Remove the temporary files and directories of `dest` (`.NAME.jdbb-PID-N.tmp`) that a process
/// which no longer runs left behind (killed, with no chance to remove them): they were never put
/// in place, so nothing of the user's is in them, and they do not pile up. Best effort.
fn remove_stale_temps(dest: &Path) {
    let prefix = format!(".{}.jdbb-", file_name(dest));
    let Ok(entries) = fs::read_dir(parent_of(dest)) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        if name
            .to_str()
            .and_then(|n| dead_pid(n, &prefix, ".tmp", true))
            .is_none()
        {
            continue;
        }
        let p = e.path();
        if fs::symlink_metadata(&p).is_ok_and(|m| m.is_dir()) {
            let _ = fs::remove_dir_all(&p);
        } else {
            let _ = fs::remove_file(&p);
        }
    }
}

/// Create a new temporary file beside `dest` (never an existing file, never through a link).
fn create_temp(dest: &Path) -> Result<(PathBuf, File)> {
    remove_stale_temps(dest);
    for n in 0..1000 {
        let tmp = temp_name(dest, n);
        // Created and registered under the lock: an interrupt removes it, or it does not exist.
        let mut v = staged();
        match OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => {
                v.push(tmp.clone());
                return Ok((tmp, f));
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
            Err(source) => {
                return Err(Error::File {
                    action: "cannot create a file beside",
                    path: dest.to_path_buf(),
                    source,
                })
            }
        }
    }
    Err(Error::File {
        action: "cannot create a file beside",
        path: dest.to_path_buf(),
        source: io::Error::new(io::ErrorKind::AlreadyExists, "1000 temporary names taken"),
    })
}

fn write_err(path: &Path) -> impl Fn(io::Error) -> Error + '_ {
    move |source| Error::File {
        action: "cannot write",
        path: path.to_path_buf(),
        source,
    }
}

/// `fsync` a directory so a rename in it is on the disk (best effort: not every system can).
fn sync_dir(dir: &Path) {
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Put the complete temporary file `tmp` in place as `dest` (see the module docs): the
/// destination is checked again; without `force` a file that appeared meanwhile is kept.
fn place(tmp: &Path, dest: &Path, force: bool) -> Result<()> {
    check_destination(dest, force)?;
    let mut v = staged();
    put(&mut v, tmp, dest, force)?;
    count_placed(&v, dest, 1);
    drop(v);
    sync_dir(parent_of(dest));
    Ok(())
}

/// [`place`]'s rename, with the lock held (`v`: the staged paths).
fn put(v: &mut Vec<PathBuf>, tmp: &Path, dest: &Path, force: bool) -> Result<()> {
    let placed = if force {
        fs::rename(tmp, dest)
    } else {
        match fs::hard_link(tmp, dest) {
            Ok(()) => fs::remove_file(tmp),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                return Err(Error::OutputExists {
                    path: dest.to_path_buf(),
                });
            }
            // A file system without hard links: the check before is the guard.
            Err(_) => fs::rename(tmp, dest),
        }
    };
    placed.map_err(write_err(dest))?;
    v.retain(|q| q != tmp);
    Ok(())
}

/// A file being written to a temporary file beside its destination, put in place by
/// [`Staged::commit`]; dropped without a commit, the temporary file is removed.
pub struct Staged {
    tmp: PathBuf,
    dest: PathBuf,
    force: bool,
    out: Option<BufWriter<File>>,
}

impl Staged {
    /// Start writing `dest` (checked first: see [`check_destination`]).
    pub fn create(dest: &Path, force: bool) -> Result<Staged> {
        check_destination(dest, force)?;
        let (tmp, f) = create_temp(dest)?;
        Ok(Staged {
            tmp,
            dest: dest.to_path_buf(),
            force,
            out: Some(BufWriter::with_capacity(1 << 16, f)),
        })
    }

    /// The destination.
    pub fn dest(&self) -> &Path {
        &self.dest
    }

    /// Flush, `fsync` and put the file in place.
    pub fn commit(mut self) -> Result<()> {
        let out = self.out.take().expect("a Staged is committed once");
        let f = out
            .into_inner()
            .map_err(|e| write_err(&self.dest)(e.into_error()))?;
        f.sync_all().map_err(write_err(&self.dest))?;
        drop(f);
        place(&self.tmp, &self.dest, self.force)
    }
}

impl Write for Staged {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match &mut self.out {
            Some(w) => w.write(buf),
            None => Err(io::Error::other("written after commit")),
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        match &mut self.out {
            Some(w) => w.flush(),
            None => Ok(()),
        }
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        if fs::symlink_metadata(&self.tmp).is_ok() {
            let _ = fs::remove_file(&self.tmp);
        }
        unregister(&self.tmp);
    }
}

/// Write `bytes` as the file `dest` (see the module docs).
pub fn write_file(dest: &Path, bytes: &[u8], force: bool) -> Result<()> {
    let mut s = Staged::create(dest, force)?;
    s.write_all(bytes).map_err(write_err(dest))?;
    s.commit()
}

/// Write the file `dest` by `write`, which is given the path of a new empty temporary file
/// beside it to fill (for writers that take a path, such as the plotting backends); then
/// `fsync` and put it in place (see the module docs).
pub fn write_via<T>(dest: &Path, force: bool, write: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    let s = Staged::create(dest, force)?;
    let value = write(&s.tmp)?;
    // What `write` wrote went through its own handle; `commit` syncs the file by path.
    File::open(&s.tmp)
        .and_then(|f| f.sync_all())
        .map_err(write_err(dest))?;
    s.commit()?;
    Ok(value)
}

/// Files written into one directory as a set: every file is staged first, then all are put in
/// place with the interrupt lock held (Ctrl-C waits for them), together with the removal of
/// files the set replaces under another name ([`FileSet::remove`]); if putting one in place
/// fails, those already replaced get their old content back, new ones are removed and removed
/// ones come back (see the module docs). Files of the directory that are not in the set are
/// kept.
pub struct FileSet {
    dir: PathBuf,
    force: bool,
    staged: Vec<Staged>,
    removals: Vec<PathBuf>,
}

/// `path` without a trailing `/` (`link/` would name what the link points at, not the link).
fn without_trailing_slash(path: &Path) -> PathBuf {
    let p: PathBuf = path.components().collect();
    if p.as_os_str().is_empty() {
        PathBuf::from(".")
    } else {
        p
    }
}

impl FileSet {
    /// A set of files in `dir` (created with the first file staged; a link or a non-directory
    /// is refused).
    pub fn new(dir: &Path, force: bool) -> Result<FileSet> {
        let dir = without_trailing_slash(dir);
        match fs::symlink_metadata(&dir) {
            Ok(m) if m.is_dir() => {}
            Ok(m) => {
                return Err(Error::OutputNotAFile {
                    path: dir.clone(),
                    what: not_a_file(&m).unwrap_or("a file, not a directory"),
                })
            }
            // Created when the first file is staged, so a refused set leaves nothing behind.
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(source) => {
                return Err(Error::File {
                    action: "cannot check",
                    path: dir.clone(),
                    source,
                })
            }
        }
        Ok(FileSet {
            dir,
            force,
            staged: vec![],
            removals: vec![],
        })
    }

    /// Check every destination of `names` in the set's directory before anything is written:
    /// each may be written ([`check_destination`]) and none is one of `inputs`
    /// ([`check_not_input`]).
    pub fn check(&self, names: &[&str], inputs: &[(&str, &Path)]) -> Result<()> {
        for n in names {
            let dest = self.dir.join(n);
            check_destination(&dest, self.force)?;
            check_not_input(&dest, inputs)?;
        }
        Ok(())
    }

    /// Stage the file `name` with `bytes`.
    pub fn add(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        if self.staged.is_empty() {
            fs::create_dir_all(&self.dir).map_err(|source| Error::File {
                action: "cannot create",
                path: self.dir.clone(),
                source,
            })?;
        }
        let dest = self.dir.join(name);
        let mut s = Staged::create(&dest, self.force)?;
        s.write_all(bytes).map_err(write_err(&dest))?;
        self.staged.push(s);
        Ok(())
    }

    /// Remove the file `name` of the directory with the set (an older member of it under
    /// another name, such as the program of another dialect), if it is a regular file.
    pub fn remove(&mut self, name: &str) {
        self.removals.push(self.dir.join(name));
    }

    /// Put every staged file in place (see the type's docs).
    pub fn commit(mut self) -> Result<()> {
        // Everything on the disk first.
        for s in &mut self.staged {
            let dest = s.dest.clone();
            let out = s.out.take().expect("staged once");
            let f = out
                .into_inner()
                .map_err(|e| write_err(&dest)(e.into_error()))?;
            f.sync_all().map_err(write_err(&dest))?;
        }
        recover_sets(&self.dir);
        for s in &self.staged {
            check_destination(&s.dest, self.force)?;
        }
        // An interrupt waits until the set is all new, or all old again.
        let mut v = staged();
        let result = self.swap(&mut v);
        drop(v);
        sync_dir(&self.dir);
        result
    }

    /// Put the set in place with the lock held (`v`): all of it, or nothing changed. A journal
    /// beside the set names what is about to change before anything does and is removed once the
    /// set is whole, so a process killed in between (SIGKILL, a power cut) is rolled back by the
    /// next set written in the directory ([`recover_sets`]).
    fn swap(&self, v: &mut Vec<PathBuf>) -> Result<()> {
        // Each destination, the old file kept for it (None: it is new), and whether it is
        // removed rather than replaced.
        let pid = std::process::id();
        let mut entries: Vec<(PathBuf, Option<PathBuf>, Option<&Staged>)> = vec![];
        for (k, s) in self.staged.iter().enumerate() {
            let existed = fs::symlink_metadata(&s.dest).is_ok();
            entries.push((
                s.dest.clone(),
                existed.then(|| backup_path(&s.dest, pid, k)),
                Some(s),
            ));
        }
        let n = entries.len();
        for (k, r) in self.removals.iter().enumerate() {
            if fs::symlink_metadata(r).is_ok_and(|m| m.is_file()) {
                entries.push((r.clone(), Some(backup_path(r, pid, n + k)), None));
            }
        }
        let journal = journal_path(&self.dir, pid);
        let mut text = String::new();
        for (dest, backup, _) in &entries {
            text.push_str(&file_name(dest));
            text.push('\t');
            if let Some(b) = backup {
                text.push_str(&file_name(b));
            }
            text.push('\n');
        }
        File::create(&journal)
            .and_then(|mut f| {
                f.write_all(text.as_bytes())?;
                f.sync_all()
            })
            .map_err(write_err(&journal))?;
        sync_dir(&self.dir);
        // What was done, to be undone on a failure.
        let mut done: Vec<(PathBuf, Option<PathBuf>)> = vec![];
        let mut result = Ok(());
        for (dest, backup, staged) in &entries {
            let keep = match (backup, staged) {
                (Some(b), Some(_)) => fs::hard_link(dest, b),
                (Some(b), None) => fs::rename(dest, b),
                (None, _) => Ok(()),
            };
            if let Err(source) = keep {
                result = Err(Error::File {
                    action: "cannot keep a copy of",
                    path: dest.clone(),
                    source,
                });
                break;
            }
            if let Some(s) = staged {
                if let Err(e) = put(v, &s.tmp, dest, self.force) {
                    if let Some(b) = backup {
                        let _ = fs::remove_file(b);
                    }
                    result = Err(e);
                    break;
                }
            }
            done.push((dest.clone(), backup.clone()));
        }
        match result {
            Ok(()) => {
                // The set is whole: the journal goes first, then the old copies.
                let _ = fs::remove_file(&journal);
                sync_dir(&self.dir);
                for b in done.iter().filter_map(|(_, b)| b.as_ref()) {
                    let _ = fs::remove_file(b);
                }
                count_placed(v, &self.dir, 1);
                Ok(())
            }
            Err(e) => {
                roll_back(&done);
                let _ = fs::remove_file(&journal);
                Err(e)
            }
        }
    }
}

/// Undo a set's changes (`done`: each destination and its old copy, None if it was new), last
/// first: old files restored, new ones removed (a copy that cannot be put back stays under its
/// .old name, so nothing is lost).
fn roll_back(done: &[(PathBuf, Option<PathBuf>)]) {
    for (dest, backup) in done.iter().rev() {
        match backup {
            Some(b) => {
                let _ = fs::rename(b, dest);
            }
            None => {
                let _ = fs::remove_file(dest);
            }
        }
    }
}

/// The old file at `dest` kept while a set is put in place: `.NAME.jdbb-PID-K.old`.
fn backup_path(dest: &Path, pid: u32, k: usize) -> PathBuf {
    dest.with_file_name(format!(".{}.jdbb-{pid}-{k}.old", file_name(dest)))
}

/// The journal of a set being put in place in `dir` by the process `pid`.
fn journal_path(dir: &Path, pid: u32) -> PathBuf {
    dir.join(format!(".jdbb-set-{pid}.journal"))
}

/// The process id in `name` if it is `PREFIX PID SUFFIX` (with `-N` after PID if `counted`), of
/// a process that no longer runs.
fn dead_pid(name: &str, prefix: &str, suffix: &str, counted: bool) -> Option<u32> {
    let rest = name.strip_prefix(prefix)?.strip_suffix(suffix)?;
    let pid = if counted {
        let (pid, n) = rest.split_once('-')?;
        n.parse::<u32>().ok()?;
        pid
    } else {
        rest
    };
    let pid = pid.parse::<u32>().ok()?;
    (pid != std::process::id() && !alive(pid)).then_some(pid)
}

/// Finish what a killed process left of a set in `dir`: a set whose journal remains was being put
/// in place, and is rolled back to the old files; old copies without a journal belong to a set
/// that was put in place whole, and are removed. Best effort; run before a set is written there.
fn recover_sets(dir: &Path) {
    let Ok(names) = entry_names(dir) else {
        return;
    };
    for name in &names {
        let Some(pid) = dead_pid(name, ".jdbb-set-", ".journal", false) else {
            continue;
        };
        let journal = dir.join(name);
        let Ok(text) = fs::read_to_string(&journal) else {
            continue;
        };
        let done: Vec<(PathBuf, Option<PathBuf>)> = text
            .lines()
            .filter_map(|l| l.split_once('\t'))
            .map(|(dest, b)| (dir.join(dest), (!b.is_empty()).then(|| dir.join(b))))
            .collect();
        // Only what had changed is undone: an old copy not yet made means its file is as it was.
        let done: Vec<_> = done
            .into_iter()
            .filter(|(_, b)| b.as_ref().is_none_or(|b| b.exists()))
            .collect();
        roll_back(&done);
        let _ = fs::remove_file(&journal);
        let _ = writeln!(
            io::stderr(),
            "note: {} held a set of files that a jdbb killed while writing it (process {pid}) had half put in place; the files before it were put back",
            dir.display()
        );
    }
    sync_dir(dir);
    for name in entry_names(dir).unwrap_or_default() {
        let is_old = name.starts_with('.')
            && name
                .split_once(".jdbb-")
                .is_some_and(|(_, rest)| dead_pid(rest, "", ".old", true).is_some());
        if is_old {
            let _ = fs::remove_file(dir.join(&name));
        }
    }
}

/// Whether `a` and `b` name the same file: the same file on the disk through any links or
/// other names (the same device and inode), or the same path.
pub fn same_file(a: &Path, b: &Path) -> bool {
    if a == b {
        return true;
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (fs::metadata(a), fs::metadata(b)) {
            return x.dev() == y.dev() && x.ino() == y.ino();
        }
    }
    match (fs::canonicalize(a), fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// Refuse an output that is one of the command's inputs: `output` (a file, or a directory
/// written whole) is one of `inputs` (each with the option that names it, as `--db`), or an
/// input is inside the directory `output`. Checked before anything is written, so the input is
/// never replaced, even with `--force`.
pub fn check_not_input(output: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    let out_dir = fs::symlink_metadata(output)
        .is_ok_and(|m| m.is_dir())
        .then(|| fs::canonicalize(output).ok())
        .flatten();
    for (option, input) in inputs {
        let inside = out_dir
            .as_ref()
            .is_some_and(|d| fs::canonicalize(input).is_ok_and(|i| i.starts_with(d)));
        if same_file(output, input) || inside {
            return Err(Error::Usage(format!(
                "{} would be written over {option} {}, an input of this command: jdbb never replaces its own input (even with --force); choose another output",
                output.display(),
                input.display()
            )));
        }
    }
    Ok(())
}

/// The file that marks a directory as written whole by [`write_dir`], so `--force` may replace
/// it (a directory without it, and not empty, is never replaced).
pub const DIR_MARK: &str = ".jdbb-output";

/// Write the directory `dest` whole: `write` fills a new directory beside it; then the new
/// directory takes `dest`'s place in one step (see the module docs). An existing `dest` is
/// replaced only with `force`, and only if it is empty or holds only what `write_dir` wrote
/// there ([`DIR_MARK`] lists it), so nothing of the user's in it is lost.
pub fn write_dir<T>(dest: &Path, force: bool, write: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    let dest = &without_trailing_slash(dest);
    let exists = check_dir_destination(dest, force)?;
    // The directories above it, as `--report a/b/c` always made them.
    fs::create_dir_all(parent_of(dest)).map_err(|source| Error::File {
        action: "cannot create the directory of",
        path: dest.to_path_buf(),
        source,
    })?;
    remove_stale_temps(dest);
    let mut stage = None;
    for n in 0..1000 {
        let p = temp_name(dest, n);
        let mut v = staged();
        match fs::create_dir(&p) {
            Ok(()) => {
                v.push(p.clone());
                stage = Some(p);
                break;
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
            Err(source) => {
                return Err(Error::File {
                    action: "cannot create a directory beside",
                    path: dest.to_path_buf(),
                    source,
                })
            }
        }
    }
    let Some(stage) = stage else {
        return Err(Error::Usage(format!(
            "cannot create a directory beside {}: 1000 temporary names taken; remove the .{}.jdbb-*.tmp directories",
            dest.display(),
            file_name(dest)
        )));
    };
    let cleanup = |stage: &Path| {
        let _ = fs::remove_dir_all(stage);
        unregister(stage);
    };
    let value = match write(&stage).and_then(|v| {
        // The mark lists what was written, so a later --force replaces only that.
        let mut mark = String::from(MARK_FIRST_LINE);
        for name in entry_names(&stage).map_err(write_err(dest))? {
            mark.push_str(&name);
            mark.push('\n');
        }
        fs::write(stage.join(DIR_MARK), mark).map_err(write_err(dest))?;
        for entry in fs::read_dir(&stage).map_err(write_err(dest))? {
            let entry = entry.map_err(write_err(dest))?;
            File::open(entry.path())
                .and_then(|f| f.sync_all())
                .map_err(write_err(&entry.path()))?;
        }
        sync_dir(&stage);
        Ok(v)
    }) {
        Ok(v) => v,
        Err(e) => {
            cleanup(&stage);
            return Err(e);
        }
    };
    // The destination may have changed while the files were written.
    if let Err(e) = check_dir_destination(dest, force) {
        cleanup(&stage);
        return Err(e);
    }
    let v = staged();
    let swapped = if exists {
        exchange(&stage, dest)
    } else {
        fs::rename(&stage, dest)
    };
    if swapped.is_ok() {
        count_placed(&v, dest, 1);
    }
    drop(v);
    if let Err(source) = swapped {
        cleanup(&stage);
        return Err(Error::File {
            action: "cannot put in place",
            path: dest.to_path_buf(),
            source,
        });
    }
    // `stage` now holds the old directory (or nothing).
    cleanup(&stage);
    sync_dir(parent_of(dest));
    Ok(value)
}

/// The first line of [`DIR_MARK`]; the names [`write_dir`] wrote follow, one a line.
const MARK_FIRST_LINE: &str = "written by jdbb as a whole; its files:\n";

/// The names in the directory `dir`, sorted.
fn entry_names(dir: &Path) -> io::Result<Vec<String>> {
    let mut names = vec![];
    for e in fs::read_dir(dir)? {
        names.push(e?.file_name().to_string_lossy().into_owned());
    }
    names.sort();
    Ok(names)
}

/// Check that [`write_dir`] may write the directory `dest` (nothing there, an empty directory,
/// or with `force` one it wrote before that holds nothing else); returns whether it exists.
/// Touches nothing.
pub fn check_dir_destination(dest: &Path, force: bool) -> Result<bool> {
    let dest = &without_trailing_slash(dest);
    let meta = match fs::symlink_metadata(dest) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(false),
        Err(source) => {
            return Err(Error::File {
                action: "cannot check",
                path: dest.to_path_buf(),
                source,
            })
        }
        Ok(m) => m,
    };
    if !meta.is_dir() {
        return Err(Error::OutputNotAFile {
            path: dest.to_path_buf(),
            what: not_a_file(&meta).unwrap_or("a file, not a directory"),
        });
    }
    let mut entries = fs::read_dir(dest).map_err(|source| Error::File {
        action: "cannot read",
        path: dest.to_path_buf(),
        source,
    })?;
    let empty = entries.next().is_none();
    if empty {
        return Ok(true);
    }
    if !force {
        return Err(Error::OutputExists {
            path: dest.to_path_buf(),
        });
    }
    if !dest.join(DIR_MARK).is_file() {
        return Err(Error::Usage(format!(
            "{} holds files that jdbb did not write as one output; it is not replaced even with --force: choose another directory, or empty it yourself",
            dest.display()
        )));
    }
    // Only what jdbb wrote there is replaced: anything else (an input, notes) is the user's.
    let mark = read_input(&dest.join(DIR_MARK), Limit::Document)?;
    let mark = String::from_utf8_lossy(&mark);
    let Some(list) = mark.strip_prefix(MARK_FIRST_LINE) else {
        // A mark of an older jdbb, without the list: nothing in it is known to be jdbb's.
        return Err(Error::Usage(format!(
            "{} was written by an older jdbb, which did not list the files it wrote there; it is not replaced even with --force, so nothing of yours in it is lost: choose another directory, or remove it yourself",
            dest.display()
        )));
    };
    let ours: Vec<&str> = list.lines().collect();
    let theirs: Vec<String> = entry_names(dest)
        .map_err(|source| Error::File {
            action: "cannot read",
            path: dest.to_path_buf(),
            source,
        })?
        .into_iter()
        .filter(|n| n != DIR_MARK && !ours.contains(&n.as_str()))
        .collect();
    if !theirs.is_empty() {
        let shown: Vec<&str> = theirs.iter().take(10).map(String::as_str).collect();
        return Err(Error::Usage(format!(
            "{} holds {} that jdbb did not write there ({}{}); it is not replaced even with --force, so they are not lost: move them out of it, or choose another directory",
            dest.display(),
            if theirs.len() == 1 { "a file" } else { "files" },
            shown.join(", "),
            if theirs.len() > shown.len() { ", …" } else { "" }
        )));
    }
    Ok(true)
}

/// Swap the directories `a` and `b` in one step where the system can (Linux
/// `renameat2(RENAME_EXCHANGE)`); elsewhere `b` is moved aside first.
fn exchange(a: &Path, b: &Path) -> io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        use std::ffi::CString;
        use std::os::unix::ffi::OsStrExt;
        let ca = CString::new(a.as_os_str().as_bytes())?;
        let cb = CString::new(b.as_os_str().as_bytes())?;
        // SAFETY: two NUL-terminated paths; the call reads them only.
        let r = unsafe {
            libc::renameat2(
                libc::AT_FDCWD,
                ca.as_ptr(),
                libc::AT_FDCWD,
                cb.as_ptr(),
                libc::RENAME_EXCHANGE,
            )
        };
        if r == 0 {
            return Ok(());
        }
        let e = io::Error::last_os_error();
        if e.raw_os_error() != Some(libc::ENOSYS) && e.raw_os_error() != Some(libc::EINVAL) {
            return Err(e);
        }
    }
    let aside = a.with_extension("old");
    fs::rename(b, &aside)?;
    if let Err(e) = fs::rename(a, b) {
        let _ = fs::rename(&aside, b);
        return Err(e);
    }
    fs::rename(&aside, a)
}

/// The kinds of input file and the most bytes read of each: above it, reading stops with an
/// error naming the limit (exit 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Limit {
    /// Long CSV tables read a row at a time (records, samples, paths): 4 GiB.
    Stream,
    /// CSV tables read whole (parameter sets, rotary runs, calibrator samples): 256 MiB.
    Table,
    /// Documents parsed whole (TOML, JSON: calibrations, plans, diagnoses, controller settings):
    /// 16 MiB.
    Document,
}

impl Limit {
    /// The limit in bytes.
    pub const fn bytes(self) -> u64 {
        match self {
            Limit::Stream => 4 << 30,
            Limit::Table => 256 << 20,
            Limit::Document => 16 << 20,
        }
    }

    /// The limit in words (`4 GiB`).
    pub fn describe(self) -> String {
        let b = self.bytes();
        if b >= 1 << 30 {
            format!("{} GiB", b >> 30)
        } else {
            format!("{} MiB", b >> 20)
        }
    }
}

/// Longest line of a CSV table, bytes: a line longer than this is not a table row.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// A reader that fails (kind `FileTooLarge`) once more than its limit has been read.
pub struct LimitedReader<R> {
    inner: R,
    left: u64,
    limit: Limit,
}

impl<R: Read> Read for LimitedReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self.left == 0 {
            // One byte more tells a file of exactly the limit from a longer one.
            let mut one = [0u8; 1];
            return match self.inner.read(&mut one)? {
                0 => Ok(0),
                _ => Err(too_large(self.limit)),
            };
        }
        let n = buf.len().min(self.left.min(usize::MAX as u64) as usize);
        let got = self.inner.read(&mut buf[..n])?;
        self.left -= got as u64;
        Ok(got)
    }
}

fn too_large(limit: Limit) -> io::Error {
    io::Error::new(
        io::ErrorKind::FileTooLarge,
        format!(
            "the file is larger than {} ({} bytes), the most jdbb reads of this kind of input; is it the right file?",
            limit.describe(),
            limit.bytes()
        ),
    )
}

/// Open the input file `path` for reading at most `limit` bytes (see the module docs): a file
/// that is missing or unreadable, a directory, or one whose size is already above the limit is
/// bad input (exit 2) with the reason.
pub fn open_input(path: &Path, limit: Limit) -> Result<LimitedReader<File>> {
    let bad = |source| Error::InputFile {
        path: path.to_path_buf(),
        source,
    };
    let file = open_no_wait(path).map_err(bad)?;
    let meta = file.metadata().map_err(bad)?;
    if meta.is_dir() {
        return Err(bad(io::Error::new(
            io::ErrorKind::InvalidInput,
            "it is a directory, not a file",
        )));
    }
    if meta.is_file() && meta.len() > limit.bytes() {
        return Err(bad(too_large(limit)));
    }
    Ok(LimitedReader {
        inner: file,
        left: limit.bytes(),
        limit,
    })
}

/// Open `path` for reading without waiting at the open: a named pipe with no writer would block
/// `open` for ever; opened without waiting, it reads as empty (then an empty input, exit 2).
/// Reads block again as usual once it is open (a pipe that has a writer is read to its end).
fn open_no_wait(path: &Path) -> io::Result<File> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        use std::os::unix::io::AsRawFd;
        let file = OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(path)?;
        let fd = file.as_raw_fd();
        // SAFETY: fcntl on a descriptor this function owns; reads and sets its status flags.
        let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
        if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) } < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(file)
    }
    #[cfg(not(unix))]
    File::open(path)
}

/// Read the whole input file `path` (at most `limit` bytes, see [`open_input`]).
pub fn read_input(path: &Path, limit: Limit) -> Result<Vec<u8>> {
    let mut bytes = vec![];
    open_input(path, limit)?
        .read_to_end(&mut bytes)
        .map_err(|source| Error::InputFile {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ls(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_file_is_replaced_only_with_force_and_never_a_link_or_device() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("a.txt");
        write_file(&f, b"one", false).unwrap();
        let e = write_file(&f, b"two", false).unwrap_err();
        assert!(e.to_string().contains("--force"), "{e}");
        assert_eq!(e.exit_code(), 2);
        assert_eq!(fs::read(&f).unwrap(), b"one");
        write_file(&f, b"two", true).unwrap();
        assert_eq!(fs::read(&f).unwrap(), b"two");
        let target = dir.path().join("target");
        fs::write(&target, "theirs").unwrap();
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        for force in [false, true] {
            let e = write_file(&link, b"x", force).unwrap_err().to_string();
            assert!(e.contains("symbolic link"), "{e}");
            let e = write_file(Path::new("/dev/null"), b"x", force)
                .unwrap_err()
                .to_string();
            assert!(e.contains("device"), "{e}");
        }
        assert_eq!(fs::read_to_string(&target).unwrap(), "theirs");
        assert_eq!(
            ls(dir.path()),
            ["a.txt", "link", "target"],
            "no temporary left"
        );
    }

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("a.txt");
        fs::write(&f, "old").unwrap();
        let e = write_via(&f, true, |_| -> Result<()> {
            Err(Error::Usage("boom".into()))
        });
        assert!(e.is_err());
        assert_eq!(fs::read_to_string(&f).unwrap(), "old");
        assert_eq!(ls(dir.path()), ["a.txt"]);
    }

    #[test]
    fn a_set_is_all_new_or_all_old() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(dir.path().join("a"), "old a").unwrap();
        fs::write(dir.path().join("b"), "old b").unwrap();
        // Without force nothing is staged over existing files.
        let set = FileSet::new(dir.path(), false).unwrap();
        assert!(set.check(&["a", "b"], &[]).is_err());
        // A set whose second file cannot be put in place (its name is a directory now).
        let mut set = FileSet::new(dir.path(), true).unwrap();
        set.add("a", b"new a").unwrap();
        set.add("b", b"new b").unwrap();
        set.add("c", b"new c").unwrap();
        fs::remove_file(dir.path().join("b")).unwrap();
        fs::create_dir(dir.path().join("b")).unwrap();
        assert!(set.commit().is_err());
        assert_eq!(fs::read_to_string(dir.path().join("a")).unwrap(), "old a");
        assert!(!dir.path().join("c").exists());
        assert_eq!(ls(dir.path()), ["a", "b"]);
        fs::remove_dir(dir.path().join("b")).unwrap();
        let mut set = FileSet::new(dir.path(), true).unwrap();
        set.add("a", b"new a").unwrap();
        set.add("b", b"new b").unwrap();
        set.commit().unwrap();
        assert_eq!(fs::read_to_string(dir.path().join("b")).unwrap(), "new b");
        assert_eq!(ls(dir.path()), ["a", "b"]);
    }

    #[test]
    fn a_directory_is_swapped_whole_and_a_foreign_one_kept() {
        let root = tempfile::tempdir().unwrap();
        let d = root.path().join("report");
        write_dir(&d, false, |s| {
            fs::write(s.join("one"), "1").map_err(write_err(s))?;
            fs::write(s.join("stale"), "1").map_err(write_err(s))
        })
        .unwrap();
        assert!(write_dir(&d, false, |_| Ok(()))
            .unwrap_err()
            .to_string()
            .contains("--force"));
        write_dir(&d, true, |s| {
            fs::write(s.join("one"), "2").map_err(write_err(s))
        })
        .unwrap();
        assert_eq!(ls(&d), [DIR_MARK, "one"], "no stale file");
        assert_eq!(ls(root.path()), ["report"], "no staging left");
        // A failing writer leaves the old directory.
        let e = write_dir(&d, true, |_| -> Result<()> {
            Err(Error::Usage("boom".into()))
        });
        assert!(e.is_err());
        assert_eq!(fs::read_to_string(d.join("one")).unwrap(), "2");
        // Missing directories above it are made.
        let deep = root.path().join("a/b/report");
        write_dir(&deep, false, |s| {
            fs::write(s.join("one"), "1").map_err(write_err(s))
        })
        .unwrap();
        assert_eq!(ls(&deep), [DIR_MARK, "one"]);
        let mine = root.path().join("mine");
        fs::create_dir(&mine).unwrap();
        fs::write(mine.join("notes"), "x").unwrap();
        let e = write_dir(&mine, true, |_| Ok(())).unwrap_err().to_string();
        assert!(e.contains("not replaced"), "{e}");
        assert_eq!(ls(&mine), ["notes"]);
    }

    #[test]
    fn force_replaces_only_what_was_written_and_never_an_input() {
        let root = tempfile::tempdir().unwrap();
        let d = root.path().join("report");
        let one = |s: &Path| fs::write(s.join("one"), "1").map_err(write_err(s));
        write_dir(&d, false, one).unwrap();
        fs::write(d.join("notes"), "mine").unwrap();
        let e = write_dir(&d, true, one).unwrap_err().to_string();
        assert!(e.contains("notes") && !e.contains("one,"), "{e}");
        assert_eq!(ls(&d), [DIR_MARK, "notes", "one"]);
        // An input inside the directory, or the same file by another name.
        let e = check_not_input(&d, &[("--samples", &d.join("one"))]).unwrap_err();
        assert!(e.to_string().contains("--samples"), "{e}");
        fs::hard_link(d.join("one"), root.path().join("alias")).unwrap();
        assert!(check_not_input(&root.path().join("alias"), &[("--db", &d.join("one"))]).is_err());
        assert!(check_not_input(&root.path().join("new"), &[("--db", &d.join("one"))]).is_ok());
        // A set removes the old member it replaces under another name, and nothing else.
        let mut set = FileSet::new(&d, true).unwrap();
        set.add("two", b"2").unwrap();
        set.remove("one");
        set.commit().unwrap();
        assert_eq!(ls(&d), [DIR_MARK, "notes", "two"]);
    }

    #[test]
    #[cfg(unix)]
    fn a_set_a_killed_process_left_half_in_place_is_rolled_back() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let mut gone = std::process::Command::new("true").spawn().unwrap();
        let pid = gone.id();
        gone.wait().unwrap();
        // Killed after `a` was replaced (its old copy kept) and `b` (new) put in place.
        fs::write(d.join("a"), "new a").unwrap();
        fs::write(d.join(format!(".a.jdbb-{pid}-0.old")), "old a").unwrap();
        fs::write(d.join("b"), "new b").unwrap();
        fs::write(
            d.join(format!(".jdbb-set-{pid}.journal")),
            format!("a\t.a.jdbb-{pid}-0.old\nb\t\nz\t.z.jdbb-{pid}-2.old\n"),
        )
        .unwrap();
        fs::write(d.join("z"), "z as it was").unwrap();
        let mut set = FileSet::new(d, true).unwrap();
        set.add("c", b"c").unwrap();
        set.commit().unwrap();
        assert_eq!(fs::read_to_string(d.join("a")).unwrap(), "old a");
        assert_eq!(fs::read_to_string(d.join("z")).unwrap(), "z as it was");
        assert_eq!(ls(d), ["a", "c", "z"]);
        // Old copies of a set that was put in place whole (no journal) are removed.
        fs::write(d.join(format!(".c.jdbb-{pid}-0.old")), "older c").unwrap();
        let mut set = FileSet::new(d, true).unwrap();
        set.add("c", b"c2").unwrap();
        set.commit().unwrap();
        assert_eq!(ls(d), ["a", "c", "z"]);
    }

    #[test]
    fn inputs_are_limited() {
        let e = read_input(Path::new("/dev/zero"), Limit::Document).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("16 MiB"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        assert!(read_input(dir.path(), Limit::Document)
            .unwrap_err()
            .to_string()
            .contains("directory"));
    }
}
