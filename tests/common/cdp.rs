//! Headless Chromium driven over the DevTools protocol, for the browser viewer's tests: a
//! minimal WebSocket client (RFC 6455: one connection, text frames, client frames masked)
//! over a loopback TCP stream, enough to open a page at a size, wait for its title,
//! evaluate expressions in it and collect what it reports to its console (errors, refused
//! requests, Content-Security-Policy violations). No npm package and no Node: Debian's
//! Chromium alone.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

/// Debian's Chromium, or a panic saying how to get it (or switch these tests off).
pub fn chromium_binary() -> PathBuf {
    ["/usr/bin/chromium", "/usr/bin/chromium-browser"]
        .into_iter()
        .map(PathBuf::from)
        .find(|p| p.exists())
        .expect(
            "Chromium is not installed (apt-get install chromium, or set RAILVIEW_SKIP_BROWSER=1 to ignore these tests)",
        )
}

/// A headless Chromium with one page, stopped (by its process id) when dropped.
pub struct Browser {
    child: Child,
    ws: TcpStream,
    session: String,
    next_id: u64,
    profile: PathBuf,
    /// Console events since [`Browser::watch_console`] (kept only once it is called).
    console: Option<Vec<Value>>,
}

impl Browser {
    /// Starts Chromium (software WebGL2: SwiftShader) with a profile in `profile` and one
    /// page of `width × height` CSS pixels at device scale 1.
    pub fn start(profile: &Path, width: u32, height: u32) -> Browser {
        std::fs::create_dir_all(profile).unwrap();
        let mut child = Command::new(chromium_binary())
            .args([
                "--headless",
                "--no-sandbox",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--ignore-gpu-blocklist",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--disable-renderer-backgrounding",
                "--disable-background-timer-throttling",
                "--remote-debugging-port=0",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg(format!("--window-size={width},{height}"))
            .arg("about:blank")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start chromium");
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if let Some(url) = line.split("DevTools listening on ").nth(1) {
                    let _ = tx.send(url.trim().to_string());
                }
            }
        });
        let url = rx
            .recv_timeout(Duration::from_secs(30))
            .expect("chromium printed no DevTools address within 30 s");
        let rest = url.strip_prefix("ws://").expect("ws:// address");
        let (host, path) = rest.split_at(rest.find('/').unwrap());
        let mut ws = TcpStream::connect(host).expect("connect to DevTools");
        ws.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
        write!(
            ws,
            "GET {path} HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
             Sec-WebSocket-Key: cmFpbHZpZXctdGVzdHMtMQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
        )
        .unwrap();
        let mut head = Vec::new();
        let mut b = [0u8; 1];
        while !head.ends_with(b"\r\n\r\n") {
            ws.read_exact(&mut b).unwrap();
            head.push(b[0]);
        }
        assert!(head.starts_with(b"HTTP/1.1 101"), "no WebSocket upgrade");
        let mut browser = Browser {
            child,
            ws,
            session: String::new(),
            next_id: 0,
            profile: profile.to_path_buf(),
            console: None,
        };
        let target = browser.call("Target.createTarget", json!({"url": "about:blank"}));
        let attached = browser.call(
            "Target.attachToTarget",
            json!({"targetId": target["targetId"], "flatten": true}),
        );
        browser.session = attached["sessionId"].as_str().unwrap().to_string();
        browser.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": width, "height": height, "deviceScaleFactor": 1, "mobile": false}),
        );
        browser
    }

    /// Calls `method` (on the page once attached) and returns its result; panics on a
    /// protocol error.
    pub fn call(&mut self, method: &str, params: Value) -> Value {
        self.next_id += 1;
        let id = self.next_id;
        let mut msg = json!({"id": id, "method": method, "params": params});
        if !self.session.is_empty() {
            msg["sessionId"] = json!(self.session);
        }
        send(&mut self.ws, msg.to_string().as_bytes());
        loop {
            let v: Value = serde_json::from_slice(&receive(&mut self.ws)).expect("DevTools JSON");
            if v["id"] == json!(id) {
                assert!(v.get("error").is_none(), "{method}: {}", v["error"]);
                return v["result"].clone();
            }
            if let (Some(kept), Some(event)) = (self.console.as_mut(), v["method"].as_str()) {
                if CONSOLE_EVENTS.contains(&event) {
                    kept.push(v);
                }
            }
        }
    }

    /// Keeps, from now on, what the page reports to its console: the `Log` domain's entries
    /// (refused requests, security and policy violations, browser messages) and the
    /// `Runtime` domain's console calls and uncaught exceptions. Call before navigating.
    pub fn watch_console(&mut self) {
        self.console = Some(Vec::new());
        self.call("Log.enable", json!({}));
        self.call("Runtime.enable", json!({}));
    }

    /// The console events kept so far (after one more round trip, so that what the page
    /// reported before this call has arrived), each as the protocol sent it.
    pub fn console_events(&mut self) -> Vec<Value> {
        self.eval("0");
        self.console.clone().unwrap_or_default()
    }

    /// Evaluates `expr` in the page (awaiting a promise) and returns its value.
    pub fn eval(&mut self, expr: &str) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": expr, "awaitPromise": true, "returnByValue": true}),
        );
        assert!(
            r.get("exceptionDetails").is_none(),
            "{expr}: {}",
            r["exceptionDetails"]
        );
        r["result"]["value"].clone()
    }

    pub fn navigate(&mut self, url: &str) {
        self.call("Page.navigate", json!({"url": url}));
    }

    /// Waits until the page's title satisfies `done` (polling), returning it; panics with
    /// the last title after `limit`.
    pub fn wait_title(&mut self, limit: Duration, done: impl Fn(&str) -> bool) -> String {
        let start = Instant::now();
        let mut title = String::new();
        while start.elapsed() < limit {
            title = self
                .eval("document.title")
                .as_str()
                .unwrap_or("")
                .to_string();
            if done(&title) {
                return title;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        // What the page itself saw: its errors, or that its script never ran (a module
        // that failed to load or to parse stops the page before it can say so).
        let errors = self.eval(
            "window.railviewErrors === undefined ? 'main.js never ran' : JSON.stringify(window.railviewErrors)",
        );
        panic!("page title still `{title}` after {limit:?}; the page's errors: {errors}");
    }
}

/// The events [`Browser::watch_console`] keeps.
const CONSOLE_EVENTS: [&str; 3] = [
    "Log.entryAdded",
    "Runtime.consoleAPICalled",
    "Runtime.exceptionThrown",
];

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        std::fs::remove_dir_all(&self.profile).ok();
    }
}

fn send(ws: &mut TcpStream, payload: &[u8]) {
    let mut frame = vec![0x81u8];
    let n = payload.len();
    if n < 126 {
        frame.push(0x80 | n as u8);
    } else if n < 65536 {
        frame.push(0x80 | 126);
        frame.extend((n as u16).to_be_bytes());
    } else {
        frame.push(0x80 | 127);
        frame.extend((n as u64).to_be_bytes());
    }
    // Mask key 0: every payload byte XOR 0 is itself.
    frame.extend([0, 0, 0, 0]);
    frame.extend_from_slice(payload);
    ws.write_all(&frame).unwrap();
}

/// One whole message (continuation frames joined; pings and other control frames skipped).
fn receive(ws: &mut TcpStream) -> Vec<u8> {
    let mut msg = Vec::new();
    loop {
        let mut h = [0u8; 2];
        ws.read_exact(&mut h).expect("DevTools frame");
        let fin = h[0] & 0x80 != 0;
        let opcode = h[0] & 0x0f;
        let mut len = (h[1] & 0x7f) as u64;
        if len == 126 {
            let mut b = [0u8; 2];
            ws.read_exact(&mut b).unwrap();
            len = u16::from_be_bytes(b) as u64;
        } else if len == 127 {
            let mut b = [0u8; 8];
            ws.read_exact(&mut b).unwrap();
            len = u64::from_be_bytes(b);
        }
        assert!(len < 1 << 30, "DevTools frame of {len} bytes");
        let mut payload = vec![0u8; len as usize];
        ws.read_exact(&mut payload).unwrap();
        if opcode >= 8 {
            assert!(opcode != 8, "DevTools closed the connection");
            continue;
        }
        msg.extend(payload);
        if fin {
            return msg;
        }
    }
}

/// Standard base64 (what `btoa` writes), decoded.
pub fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => (c - b'A') as u32,
            b'a'..=b'z' => (c - b'a' + 26) as u32,
            b'0'..=b'9' => (c - b'0' + 52) as u32,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {c}"),
        }
    };
    let b: Vec<u8> = s.bytes().filter(|&c| c != b'=').collect();
    let mut out = Vec::with_capacity(b.len() * 3 / 4);
    for chunk in b.chunks(4) {
        let mut v = 0u32;
        for (i, &c) in chunk.iter().enumerate() {
            v |= val(c) << (18 - 6 * i);
        }
        for i in 0..chunk.len().saturating_sub(1) {
            out.push((v >> (16 - 8 * i)) as u8);
        }
    }
    out
}
