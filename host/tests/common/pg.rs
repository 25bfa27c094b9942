//! A throwaway PostgreSQL cluster for the history tests: Debian's server (scripts/setup.sh
//! installs it), initialised and run as an unprivileged user (`nobody` when the tests run as
//! root: initdb refuses root) in a temporary directory, listening on a free loopback port and a
//! socket in that directory; started once per test binary and stopped when it exits. The role
//! `jdbb` logs in with a password (so the tests see that it never prints); each test gets a
//! database of its own.
//!
//! Without PostgreSQL the tests that need it skip with a message, or fail when
//! `JDBB_REQUIRE_POSTGRES=1` (scripts/test.sh sets it).
use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::OnceLock;

/// The role's password: a test asserts it never appears in jdbb's output.
pub const PASSWORD: &str = "pw-Secret-4711";

/// A running cluster.
pub struct Cluster {
    pub dir: PathBuf,
    pub port: u16,
    bin: PathBuf,
    /// The user the server runs as, when the tests run as root.
    user: Option<&'static str>,
}

static CLUSTER: OnceLock<Option<Cluster>> = OnceLock::new();

/// Debian's server binaries (the newest version installed), if any.
fn server_bin() -> Option<PathBuf> {
    let mut versions: Vec<PathBuf> = std::fs::read_dir("/usr/lib/postgresql")
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path().join("bin")))
        .filter(|b| b.join("initdb").exists())
        .collect();
    versions.sort();
    versions.pop()
}

/// `program args` as the cluster's user.
fn as_user(user: Option<&str>, program: PathBuf, args: &[&str]) -> Command {
    match user {
        Some(u) => {
            let mut c = Command::new("runuser");
            c.args(["-u", u, "--"]).arg(program).args(args);
            c
        }
        None => {
            let mut c = Command::new(program);
            c.args(args);
            c
        }
    }
}

/// Run `c`, which must succeed.
fn must(mut c: Command, what: &str) {
    let o = c.output().unwrap_or_else(|e| panic!("{what}: {e}"));
    assert!(
        o.status.success(),
        "{what}: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

extern "C" fn stop_cluster() {
    if let Some(Some(c)) = CLUSTER.get() {
        let data = c.dir.join("data");
        let _ = as_user(
            c.user,
            c.bin.join("pg_ctl"),
            &[
                "-D",
                data.to_str().unwrap(),
                "-m",
                "immediate",
                "-w",
                "stop",
            ],
        )
        .output();
        let _ = std::fs::remove_dir_all(&c.dir);
    }
}

fn start() -> Option<Cluster> {
    let Some(bin) = server_bin() else {
        let msg = "PostgreSQL not found in /usr/lib/postgresql (scripts/setup.sh installs it)";
        if std::env::var("JDBB_REQUIRE_POSTGRES").as_deref() == Ok("1") {
            panic!("{msg}");
        }
        eprintln!("skipped: {msg}");
        return None;
    };
    let root = unsafe { libc::geteuid() } == 0;
    let user = root.then_some("nobody");
    let dir = tempfile::Builder::new()
        .prefix("jdbb-pg-")
        .tempdir()
        .unwrap()
        .keep();
    if root {
        let name = std::ffi::CString::new("nobody").unwrap();
        let pw = unsafe { libc::getpwnam(name.as_ptr()) };
        assert!(!pw.is_null(), "no user nobody to run PostgreSQL as");
        let (uid, gid) = unsafe { ((*pw).pw_uid, (*pw).pw_gid) };
        let path = std::ffi::CString::new(dir.to_str().unwrap()).unwrap();
        assert_eq!(unsafe { libc::chown(path.as_ptr(), uid, gid) }, 0);
    }
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let data = dir.join("data");
    let pwfile = dir.join("pw");
    std::fs::write(&pwfile, PASSWORD).unwrap();
    if root {
        let path = std::ffi::CString::new(pwfile.to_str().unwrap()).unwrap();
        unsafe { libc::chmod(path.as_ptr(), 0o644) };
    }
    must(
        as_user(
            user,
            bin.join("initdb"),
            &[
                "-D",
                data.to_str().unwrap(),
                "-U",
                "postgres",
                "--auth-local=trust",
                "--auth-host=scram-sha-256",
                "--pwfile",
                pwfile.to_str().unwrap(),
                "-E",
                "UTF8",
            ],
        ),
        "initdb",
    );
    let options = format!(
        "-c listen_addresses=127.0.0.1 -p {port} -k {} -c max_connections=60 -c fsync=off",
        dir.display()
    );
    must(
        as_user(
            user,
            bin.join("pg_ctl"),
            &[
                "-D",
                data.to_str().unwrap(),
                "-o",
                &options,
                "-l",
                dir.join("log").to_str().unwrap(),
                "-w",
                "start",
            ],
        ),
        "pg_ctl start",
    );
    let cluster = Cluster {
        dir,
        port,
        bin,
        user,
    };
    cluster.psql(&format!(
        "CREATE ROLE jdbb LOGIN PASSWORD '{PASSWORD}' CREATEDB"
    ));
    Some(cluster)
}

/// The test binary's cluster, started on first use (None: no PostgreSQL here, test skipped).
pub fn cluster() -> Option<&'static Cluster> {
    let c = CLUSTER.get_or_init(|| {
        let c = start();
        if c.is_some() {
            unsafe { libc::atexit(stop_cluster) };
        }
        c
    });
    c.as_ref()
}

static DATABASES: AtomicU32 = AtomicU32::new(0);

impl Cluster {
    /// Run `sql` as the superuser over the cluster's socket.
    pub fn psql(&self, sql: &str) -> String {
        self.psql_in("postgres", sql)
    }

    /// `sql` in database `db`, as the superuser.
    pub fn psql_in(&self, db: &str, sql: &str) -> String {
        let o = Command::new(self.bin.join("psql"))
            .args(["-h", self.dir.to_str().unwrap(), "-p"])
            .arg(self.port.to_string())
            .args([
                "-U",
                "postgres",
                "-d",
                db,
                "-tAX",
                "-v",
                "ON_ERROR_STOP=1",
                "-c",
                sql,
            ])
            .output()
            .expect("psql");
        assert!(
            o.status.success(),
            "psql {sql}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        String::from_utf8_lossy(&o.stdout).trim().to_string()
    }

    /// A new empty database owned by `jdbb`: (its name, its URL with the password).
    pub fn database(&self) -> (String, String) {
        let name = format!(
            "t{}_{}",
            std::process::id(),
            DATABASES.fetch_add(1, Ordering::SeqCst)
        );
        self.psql(&format!("CREATE DATABASE {name} OWNER jdbb"));
        let url = format!("postgres://jdbb:{PASSWORD}@127.0.0.1:{}/{name}", self.port);
        (name, url)
    }
}
