//! nginx on loopback for the static-host tests: an unprivileged configuration in a scratch
//! directory (pid, logs and temporary paths there, a free port), the README's own `server`
//! block where a test serves a database as the README says (checked to send the headers
//! `railview serve` sends), and a raw HTTP/1.1 GET to look at headers.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A running nginx, stopped (by its process id) when dropped.
pub struct Nginx {
    child: Child,
    pub port: u16,
    pub dir: PathBuf,
}

/// The nginx binary, or a panic saying how to get it (or switch these tests off).
pub fn nginx_binary() -> PathBuf {
    let found = std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .chain([PathBuf::from("/usr/sbin")])
        .map(|d| d.join("nginx"))
        .find(|p| p.is_file());
    found.unwrap_or_else(|| {
        panic!(
            "nginx is not installed: apt-get install nginx (scripts/test.sh does), or set \
             RAILVIEW_SKIP_NGINX_TESTS=1 to mark the static-host tests ignored"
        )
    })
}

/// The README's nginx `server` block for a database root `root`, listening on loopback at
/// `port` (its `listen` and `root` lines replaced, nothing else).
pub fn readme_server_block(root: &Path, port: u16) -> String {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md"))
        .expect("README.md");
    let start = readme
        .find("```nginx\n")
        .expect("README has an nginx block")
        + 9;
    let block = &readme[start..];
    let block = &block[..block.find("```").expect("nginx block ends")];
    let mut out = String::new();
    let (mut listen, mut rooted) = (false, false);
    for line in block.lines() {
        let t = line.trim_start();
        if t.starts_with("listen ") {
            out += &format!("    listen 127.0.0.1:{port};\n");
            listen = true;
        } else if t.starts_with("root ") {
            out += &format!("    root {};\n", root.display());
            rooted = true;
        } else {
            out += line;
            out.push('\n');
        }
    }
    assert!(
        listen && rooted,
        "the README's server block has listen and root lines"
    );
    for line in security_header_lines() {
        assert!(
            block.contains(&line),
            "the README's server block lacks `{line}`: it sends what `railview serve` sends"
        );
    }
    out
}

/// nginx's `add_header` lines for the headers `railview serve` sends with every answer
/// (`streamer::server::SECURITY_HEADERS`), on error answers too.
fn security_header_lines() -> Vec<String> {
    streamer::server::SECURITY_HEADERS
        .iter()
        .map(|(name, value)| format!("add_header {name} \"{value}\" always;"))
        .collect()
}

/// A port free on loopback now (nginx binds it next; a race with another process is
/// retried by [`Nginx::start`]).
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}

impl Nginx {
    /// Start nginx in `dir` (created) with `http_body` (server blocks and anything else of
    /// the `http` context) made by `make(port)`; waits until it accepts connections.
    pub fn start(dir: &Path, make: impl Fn(u16) -> String) -> Nginx {
        std::fs::create_dir_all(dir).unwrap();
        let bin = nginx_binary();
        for attempt in 0..5 {
            let port = free_port();
            let temp = dir.join("temp");
            for sub in ["body", "proxy", "fastcgi", "uwsgi", "scgi", "cache"] {
                std::fs::create_dir_all(temp.join(sub)).unwrap();
            }
            // Run as root, nginx's workers switch to `nobody`: they must be able to write
            // its temporary and cache directories.
            open_up(&temp);
            let conf = format!(
                "daemon off;\n\
                 worker_processes 1;\n\
                 pid {d}/nginx.pid;\n\
                 error_log {d}/error.log warn;\n\
                 events {{ worker_connections 256; }}\n\
                 http {{\n\
                 access_log {d}/access.log;\n\
                 client_body_temp_path {t}/body;\n\
                 proxy_temp_path {t}/proxy;\n\
                 fastcgi_temp_path {t}/fastcgi;\n\
                 uwsgi_temp_path {t}/uwsgi;\n\
                 scgi_temp_path {t}/scgi;\n\
                 {body}\n\
                 }}\n",
                d = dir.display(),
                t = temp.display(),
                body = make(port)
            );
            std::fs::write(dir.join("nginx.conf"), conf).unwrap();
            let mut child = Command::new(&bin)
                .arg("-p")
                .arg(dir)
                .arg("-c")
                .arg(dir.join("nginx.conf"))
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("start nginx");
            let start = Instant::now();
            while start.elapsed() < Duration::from_secs(10) {
                if let Ok(Some(_)) = child.try_wait() {
                    break;
                }
                if TcpStream::connect(("127.0.0.1", port)).is_ok() {
                    return Nginx {
                        child,
                        port,
                        dir: dir.to_path_buf(),
                    };
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = child.kill();
            let _ = child.wait();
            let log = std::fs::read_to_string(dir.join("error.log")).unwrap_or_default();
            assert!(attempt < 4, "nginx did not start: {log}");
        }
        unreachable!("nginx start attempts")
    }

    pub fn url(&self, prefix: &str) -> String {
        format!("http://127.0.0.1:{}{prefix}", self.port)
    }

    /// nginx's error log so far (for assertion messages).
    pub fn errors(&self) -> String {
        std::fs::read_to_string(self.dir.join("error.log")).unwrap_or_default()
    }
}

impl Drop for Nginx {
    /// SIGTERM to the master (it stops its workers), SIGKILL if it has not gone in 5 s.
    fn drop(&mut self) {
        let pid = self.child.id().to_string();
        let _ = Command::new("kill").args(["-TERM", &pid]).status();
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(5) {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `dir` and everything under it writable by nginx's unprivileged workers.
fn open_up(dir: &Path) {
    use std::os::unix::fs::PermissionsExt;
    for entry in walk(dir) {
        let _ = std::fs::set_permissions(&entry, std::fs::Permissions::from_mode(0o777));
    }
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = vec![dir.to_path_buf()];
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(walk(&p));
            } else {
                out.push(p);
            }
        }
    }
    out
}

/// A response read whole: status, headers (names lower-case), body.
pub struct Response {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Response {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }
}

/// `GET path` on `127.0.0.1:port` with `extra` header lines, `Connection: close`.
pub fn get(port: u16, path: &str, extra: &[(&str, &str)]) -> Response {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    let mut req = format!("GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n");
    for (k, v) in extra {
        req += &format!("{k}: {v}\r\n");
    }
    req += "\r\n";
    s.write_all(req.as_bytes()).unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("response headers end");
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let mut lines = head.split("\r\n");
    let status = lines
        .next()
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|c| c.parse().ok())
        .expect("status line");
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    let mut body = raw[split + 4..].to_vec();
    if headers
        .iter()
        .any(|(k, v)| k == "transfer-encoding" && v.contains("chunked"))
    {
        body = dechunk(&body);
    }
    Response {
        status,
        headers,
        body,
    }
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let Some(eol) = b.windows(2).position(|w| w == b"\r\n") else {
            return out;
        };
        let size = usize::from_str_radix(
            String::from_utf8_lossy(&b[..eol])
                .split(';')
                .next()
                .unwrap_or("0")
                .trim(),
            16,
        )
        .unwrap_or(0);
        if size == 0 || b.len() < eol + 2 + size {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + size]);
        b = &b[(eol + 4 + size).min(b.len())..];
    }
}
