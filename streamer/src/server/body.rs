//! Response bodies that hold at most [`CHUNK_BYTES`] of file data at a time.
//!
//! An object or byte range, or a `/bundle` of many, is a list of [`Segment`]s (file, offset,
//! length). A body of at most one chunk is read whole before the response starts
//! ([`read_small`], on the connection's own task, as nginx reads files without its thread
//! pool: a page-cache read of a few KiB costs less than a hop to another thread); a longer
//! one is read a chunk at a time on the blocking pool as the connection takes it
//! ([`FileStream`]), one file open at a time. A peer that does not read
//! therefore makes the server hold one chunk (plus the connection's write buffer), however
//! large the response: the bytes a request can make the server hold are bounded by the
//! chunk, not by what it asks for.

use std::collections::VecDeque;
use std::future::Future as _;
use std::io::{self, Read, Seek, SeekFrom};
use std::path::PathBuf;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use bytes::Bytes;
use hyper::body::{Frame, SizeHint};
use tokio::task::JoinHandle;

use super::admit::{Clock, ConnState};

/// File data a response holds at most while it streams.
pub const CHUNK_BYTES: usize = 32 * 1024;

/// A byte range of a file, or (with `text`) a few bytes of the response itself (the part
/// headers of a `multipart/byteranges` answer; `path` and `offset` unused, `len` their
/// length).
#[derive(Clone, Debug)]
pub(crate) struct Segment {
    pub path: PathBuf,
    pub offset: u64,
    pub len: u64,
    pub text: Option<Bytes>,
}

impl Segment {
    pub(crate) fn file(path: PathBuf, offset: u64, len: u64) -> Segment {
        Segment {
            path,
            offset,
            len,
            text: None,
        }
    }

    pub(crate) fn text(text: impl Into<Bytes>) -> Segment {
        let text = text.into();
        Segment {
            path: PathBuf::new(),
            offset: 0,
            len: text.len() as u64,
            text: Some(text),
        }
    }
}

/// Reads segments one after another, keeping one file open.
struct Reader {
    segments: VecDeque<Segment>,
    file: Option<std::fs::File>,
    /// The front segment's bytes when it is text, not a file.
    text: Option<Bytes>,
    /// Bytes left in the front segment once `file` is open at its position.
    left: u64,
    /// Bytes produced so far, and the byte to flip (fault injection), if any.
    produced: u64,
    corrupt_at: Option<u64>,
}

impl Reader {
    fn new(segments: Vec<Segment>, corrupt_at: Option<u64>) -> Reader {
        Reader {
            segments: segments.into(),
            file: None,
            text: None,
            left: 0,
            produced: 0,
            corrupt_at,
        }
    }

    /// Up to `max` bytes, continuing across segments.
    fn next_chunk(&mut self, max: usize) -> io::Result<Vec<u8>> {
        let mut out = Vec::new();
        while out.len() < max {
            if (self.file.is_none() && self.text.is_none()) || self.left == 0 {
                let Some(seg) = self.segments.pop_front() else {
                    break;
                };
                self.file = None;
                self.text = None;
                if let Some(t) = seg.text {
                    self.left = t.len() as u64;
                    self.text = Some(t);
                } else {
                    let mut f = std::fs::File::open(&seg.path)?;
                    f.seek(SeekFrom::Start(seg.offset))?;
                    self.file = Some(f);
                    self.left = seg.len;
                }
                if self.left == 0 {
                    continue;
                }
            }
            let want = (max - out.len()).min(self.left as usize);
            let start = out.len();
            out.reserve(want);
            if let Some(t) = &self.text {
                let at = t.len() - self.left as usize;
                out.extend_from_slice(&t[at..at + want]);
            } else if let Some(f) = self.file.as_mut() {
                // Into the spare capacity, no zeroing first.
                f.take(want as u64).read_to_end(&mut out)?;
            }
            if out.len() - start < want {
                return Err(io::ErrorKind::UnexpectedEof.into());
            }
            self.left -= want as u64;
            if self.left == 0 {
                self.file = None;
                self.text = None;
            }
        }
        if let Some(i) = self.corrupt_at {
            if (self.produced..self.produced + out.len() as u64).contains(&i) {
                out[(i - self.produced) as usize] ^= 0x5a;
            }
        }
        self.produced += out.len() as u64;
        Ok(out)
    }
}

/// Read `segments` whole (a body of at most a few chunks; the caller checks the size).
pub(crate) fn read_small(segments: Vec<Segment>, corrupt_at: Option<u64>) -> io::Result<Bytes> {
    let total: u64 = segments.iter().map(|s| s.len).sum();
    let mut r = Reader::new(segments, corrupt_at);
    let data = r.next_chunk(total as usize)?;
    if (data.len() as u64) < total {
        return Err(io::ErrorKind::UnexpectedEof.into());
    }
    Ok(Bytes::from(data))
}

/// A body streamed from files a chunk at a time.
pub(crate) struct FileStream {
    reader: Option<Reader>,
    task: Option<JoinHandle<(Reader, io::Result<Vec<u8>>)>>,
    remaining: u64,
}

impl FileStream {
    pub(crate) fn new(segments: Vec<Segment>, corrupt_at: Option<u64>) -> FileStream {
        let remaining = segments.iter().map(|s| s.len).sum();
        FileStream {
            reader: Some(Reader::new(segments, corrupt_at)),
            task: None,
            remaining,
        }
    }

    fn poll_chunk(&mut self, cx: &mut Context<'_>) -> Poll<Option<io::Result<Bytes>>> {
        loop {
            if let Some(task) = self.task.as_mut() {
                let done = std::task::ready!(Pin::new(task).poll(cx));
                self.task = None;
                let (reader, res) = match done {
                    Ok(r) => r,
                    Err(e) => return Poll::Ready(Some(Err(io::Error::other(e)))),
                };
                self.reader = Some(reader);
                return Poll::Ready(Some(match res {
                    Ok(data) if data.is_empty() => {
                        // The files are shorter than they were when the response started.
                        self.remaining = 0;
                        Err(io::ErrorKind::UnexpectedEof.into())
                    }
                    Ok(data) => {
                        self.remaining = self.remaining.saturating_sub(data.len() as u64);
                        Ok(Bytes::from(data))
                    }
                    Err(e) => {
                        self.remaining = 0;
                        Err(e)
                    }
                }));
            }
            if self.remaining == 0 {
                return Poll::Ready(None);
            }
            let Some(mut reader) = self.reader.take() else {
                return Poll::Ready(None);
            };
            let max = (self.remaining as usize).min(CHUNK_BYTES);
            self.task = Some(tokio::task::spawn_blocking(move || {
                let r = reader.next_chunk(max);
                (reader, r)
            }));
        }
    }
}

/// A response body: bytes in memory or a file stream. When the connection has taken all of
/// it (or dropped it), the connection's state is told the response is over.
pub struct ServeBody {
    kind: Kind,
    done: Option<(Arc<ConnState>, Clock)>,
}

enum Kind {
    Full(Option<Bytes>),
    Files(FileStream),
}

impl ServeBody {
    pub(crate) fn full(b: impl Into<Bytes>) -> ServeBody {
        let b = b.into();
        ServeBody {
            kind: Kind::Full((!b.is_empty()).then_some(b)),
            done: None,
        }
    }

    pub(crate) fn empty() -> ServeBody {
        ServeBody::full(Bytes::new())
    }

    pub(crate) fn files(s: FileStream) -> ServeBody {
        ServeBody {
            kind: Kind::Files(s),
            done: None,
        }
    }

    /// Tell `state` when this body is finished.
    pub(crate) fn report_to(mut self, state: Arc<ConnState>, clock: Clock) -> ServeBody {
        self.done = Some((state, clock));
        self
    }

    fn finish(&mut self) {
        if let Some((state, clock)) = self.done.take() {
            state.end_response(clock.now_ms());
        }
    }
}

impl Drop for ServeBody {
    fn drop(&mut self) {
        self.finish();
    }
}

impl hyper::body::Body for ServeBody {
    type Data = Bytes;
    type Error = io::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, io::Error>>> {
        let this = self.get_mut();
        let r = match &mut this.kind {
            Kind::Full(b) => Poll::Ready(b.take().map(|b| Ok(Frame::data(b)))),
            Kind::Files(s) => s.poll_chunk(cx).map(|o| o.map(|r| r.map(Frame::data))),
        };
        if let Poll::Ready(None) = r {
            this.finish();
        }
        r
    }

    fn is_end_stream(&self) -> bool {
        match &self.kind {
            Kind::Full(b) => b.is_none(),
            Kind::Files(s) => s.remaining == 0 && s.task.is_none(),
        }
    }

    fn size_hint(&self) -> SizeHint {
        match &self.kind {
            Kind::Full(b) => SizeHint::with_exact(b.as_ref().map_or(0, |b| b.len() as u64)),
            Kind::Files(s) => SizeHint::with_exact(s.remaining),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use http_body_util::BodyExt;
    use hyper::body::Body as _;

    #[tokio::test]
    async fn segments_stream_in_chunks_across_files_and_match_a_whole_read() {
        let dir = std::env::temp_dir().join(format!("railview-body-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let a: Vec<u8> = (0..100_000u32).map(|i| (i * 7) as u8).collect();
        let b: Vec<u8> = (0..5_000u32).map(|i| (i * 13 + 1) as u8).collect();
        std::fs::write(dir.join("a"), &a).unwrap();
        std::fs::write(dir.join("b"), &b).unwrap();
        let segs = vec![
            Segment::file(dir.join("a"), 10, 70_000),
            Segment::text(&b"--text--"[..]),
            Segment::file(dir.join("b"), 0, 5_000),
            Segment::file(dir.join("a"), 99_990, 10),
        ];
        let mut want = a[10..70_010].to_vec();
        want.extend_from_slice(b"--text--");
        want.extend_from_slice(&b);
        want.extend_from_slice(&a[99_990..]);
        let mut body = ServeBody::files(FileStream::new(segs.clone(), None));
        assert_eq!(body.size_hint().exact(), Some(want.len() as u64));
        let mut got = Vec::new();
        let mut frames = 0;
        while let Some(f) = body.frame().await {
            let d = f.unwrap().into_data().unwrap();
            assert!(d.len() <= CHUNK_BYTES);
            got.extend_from_slice(&d);
            frames += 1;
        }
        assert_eq!(got, want);
        assert_eq!(frames, want.len().div_ceil(CHUNK_BYTES));
        assert_eq!(read_small(segs.clone(), None).unwrap(), want);
        // Fault injection flips exactly one byte, wherever it falls.
        let bad = read_small(segs.clone(), Some(40_000)).unwrap();
        assert_eq!(bad.iter().zip(&want).filter(|(x, y)| x != y).count(), 1);
        // A file shorter than its segment ends the body with an error, not a short body.
        let short = vec![Segment::file(dir.join("b"), 4_000, 60_000)];
        let mut body = ServeBody::files(FileStream::new(short, None));
        let mut failed = false;
        while let Some(f) = body.frame().await {
            failed |= f.is_err();
        }
        assert!(failed);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
