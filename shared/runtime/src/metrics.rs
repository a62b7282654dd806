//! Metrics of one process: CSV rows and TensorBoard scalars side by side.
//!
//! Invariants: the CSV's columns are fixed by its header (the first row written,
//! or the existing header when a resumed process appends); every row is flushed
//! when written, so a killed process loses at most the row being written. The
//! TensorBoard file is a TFRecord stream of `Event` protos (wall time, step,
//! `simple_value` summaries), each record framed by masked CRC-32C checksums as
//! TensorBoard's reader expects; a resumed process starts a new event file.
//!
//! A write that fails (a full disk) loses nothing and stops nothing: the row (or
//! record) stays in memory, whatever part of it reached the file is cut off again,
//! and every later call first retries what waits, in order — so once space is freed
//! the files hold every row, whole. [`Metrics::failing`] says what is waiting and why.
//! Memory is bounded: past [`MAX_WAITING`] waiting records of one file, newer records
//! are dropped and counted ([`MetricsFailure::dropped`]) rather than queued.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Seek, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use crate::error::{Result, RuntimeError};

/// Records of one file that may wait in memory for the disk (about 10 MB of CSV rows,
/// more than a day of episode rows at the reference rates); newer ones are dropped.
pub const MAX_WAITING: usize = 100_000;

/// CSV + TensorBoard writer for one process.
pub struct Metrics {
    csv: AppendFile,
    columns: Vec<String>,
    tb: TbWriter,
}

/// A file written by whole records (lines of a CSV, TensorBoard records): a record
/// that cannot be written whole stays in memory (the part that reached the file cut
/// off again) and is retried first at the next write, so a full disk loses nothing
/// and the file never holds half a record.
pub struct AppendFile {
    file: File,
    path: PathBuf,
    waiting: std::collections::VecDeque<Vec<u8>>,
    /// Records not queued because [`MAX_WAITING`] were already waiting.
    dropped: u64,
    error: Option<std::io::Error>,
    /// Writes still to fail as a full disk would, half a record written (tests).
    inject: usize,
}

impl AppendFile {
    fn new(file: File, path: PathBuf) -> AppendFile {
        AppendFile { file, path, waiting: Default::default(), dropped: 0, error: None, inject: 0 }
    }

    /// Open `path` for appending (created when missing).
    pub fn open(path: &Path) -> Result<AppendFile> {
        let file = OpenOptions::new().create(true).append(true).open(path).map_err(|e| RuntimeError::file(path, e))?;
        Ok(AppendFile::new(file, path.to_path_buf()))
    }

    /// When the last write failed: the file, the records waiting and the error.
    pub fn failure(&self) -> Option<MetricsFailure<'_>> {
        self.error.as_ref().map(|error| MetricsFailure {
            path: &self.path,
            waiting: self.waiting.len(),
            dropped: self.dropped,
            error,
        })
    }

    fn write_record(&mut self, record: &[u8]) -> std::io::Result<()> {
        if self.inject > 0 {
            self.inject -= 1;
            self.file.write_all(&record[..record.len() / 2])?;
            return Err(std::io::Error::from(std::io::ErrorKind::StorageFull));
        }
        self.file.write_all(record)?;
        self.file.flush()
    }

    /// Queue `record` and write everything queued, in order, until a write fails.
    pub fn append(&mut self, record: Vec<u8>) {
        if self.waiting.len() >= MAX_WAITING {
            self.write_waiting();
        }
        if self.waiting.len() >= MAX_WAITING {
            self.dropped += 1;
        } else {
            self.waiting.push_back(record);
        }
        self.write_waiting();
    }

    /// Write the waiting records, in order, until a write fails.
    fn write_waiting(&mut self) {
        while let Some(next) = self.waiting.front().cloned() {
            let at = self.file.metadata().map(|m| m.len()).ok();
            match self.write_record(&next) {
                Ok(()) => {
                    self.waiting.pop_front();
                    self.error = None;
                }
                Err(e) => {
                    // Cut the partial record off and write the next try where it began
                    // (a file not opened for appending keeps its cursor past the cut).
                    if let Some(len) = at {
                        let _ = self.file.set_len(len);
                        let _ = self.file.seek(std::io::SeekFrom::Start(len));
                    }
                    self.error = Some(e);
                    return;
                }
            }
        }
    }
}

/// Why rows of a [`Metrics`] (or an [`AppendFile`]) are waiting in memory.
#[derive(Debug)]
pub struct MetricsFailure<'a> {
    /// The file that cannot be written.
    pub path: &'a Path,
    /// Records waiting for it.
    pub waiting: usize,
    /// Records dropped since the file was opened because [`MAX_WAITING`] were waiting.
    pub dropped: u64,
    /// The last write's error.
    pub error: &'a std::io::Error,
}

impl Metrics {
    /// Open `<metrics_dir>/<name>.csv` (appending when it exists) and a new event
    /// file under `<tb_dir>/<name>/`.
    pub fn open(metrics_dir: &Path, tb_dir: &Path, name: &str) -> Result<Metrics> {
        let csv_path = metrics_dir.join(format!("{name}.csv"));
        let columns = match File::open(&csv_path) {
            Ok(f) => BufReader::new(f)
                .lines()
                .next()
                .and_then(|l| l.ok())
                .map(|l| l.split(',').map(str::to_string).collect())
                .unwrap_or_default(),
            Err(_) => Vec::new(),
        };
        let csv = AppendFile::open(&csv_path)?;
        let tb = TbWriter::create(&tb_dir.join(name))?;
        Ok(Metrics { csv, columns, tb })
    }

    /// Make the next `n` writes of each file fail as a full disk does, after writing
    /// half their record (tests of the recovery).
    #[doc(hidden)]
    pub fn inject_disk_full(&mut self, n: usize) {
        self.csv.inject = n;
        self.tb.file.inject = n;
    }

    /// When a write failed: the file, the records waiting in memory and the error
    /// (the CSV's first, then the TensorBoard file's); `None` when all is written.
    pub fn failing(&self) -> Option<MetricsFailure<'_>> {
        self.csv.failure().or_else(|| self.tb.file.failure())
    }

    /// Write one row: `step` plus named values. The first row fixes the columns;
    /// later rows must name the same values (missing ones are left empty). A row the
    /// disk does not take waits in memory ([`Metrics::failing`]); it is not an error.
    pub fn log(&mut self, step: u64, values: &[(&str, f64)]) -> Result<()> {
        let values: Vec<(&str, Option<f64>)> = values.iter().map(|&(k, v)| (k, Some(v))).collect();
        self.log_optional(step, &values)
    }

    /// [`Metrics::log`] with values that may not exist yet (a statistic before its
    /// first sample, a fit before the first fit): a `None` still names its column, its
    /// CSV cell stays empty and TensorBoard gets no point — never a placeholder NaN.
    pub fn log_optional(&mut self, step: u64, values: &[(&str, Option<f64>)]) -> Result<()> {
        if self.columns.is_empty() {
            self.columns = std::iter::once(crate::columns::STEP.to_string())
                .chain(values.iter().map(|(k, _)| k.to_string()))
                .collect();
            self.csv.append(format!("{}\n", self.columns.join(",")).into_bytes());
        }
        let mut row = Vec::with_capacity(self.columns.len());
        for c in &self.columns {
            if c == crate::columns::STEP {
                row.push(step.to_string());
            } else {
                let value = values.iter().find(|(k, _)| k == c).and_then(|(_, v)| *v);
                row.push(value.map(|v| format!("{v}")).unwrap_or_default());
            }
        }
        self.csv.append(format!("{}\n", row.join(",")).into_bytes());
        let present: Vec<(&str, f64)> = values.iter().filter_map(|&(k, v)| Some((k, v?))).collect();
        self.tb.scalars(step, &present);
        Ok(())
    }
}

/// A TensorBoard event-file writer (scalars only); records the disk does not take
/// wait in memory, as the CSV's rows do.
pub struct TbWriter {
    file: AppendFile,
}

fn masked_crc(data: &[u8]) -> u32 {
    let c = crc32c::crc32c(data);
    (c.rotate_right(15)).wrapping_add(0xa282_ead8)
}

fn varint(mut v: u64, out: &mut Vec<u8>) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn len_delimited(field: u32, bytes: &[u8], out: &mut Vec<u8>) {
    varint(((field << 3) | 2) as u64, out);
    varint(bytes.len() as u64, out);
    out.extend_from_slice(bytes);
}

fn wall_time() -> f64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0)
}

/// Encode an `Event { wall_time, step, [file_version | summary] }`.
fn event(step: u64, file_version: Option<&str>, scalars: &[(&str, f64)]) -> Vec<u8> {
    let mut e = Vec::new();
    e.push(0x09); // field 1, fixed64: wall_time
    e.extend_from_slice(&wall_time().to_le_bytes());
    e.push(0x10); // field 2, varint: step
    varint(step, &mut e);
    if let Some(v) = file_version {
        len_delimited(3, v.as_bytes(), &mut e);
    }
    if !scalars.is_empty() {
        let mut summary = Vec::new();
        for (tag, value) in scalars {
            let mut v = Vec::new();
            len_delimited(1, tag.as_bytes(), &mut v); // Value.tag
            v.push(0x15); // field 2, fixed32: simple_value
            v.extend_from_slice(&(*value as f32).to_le_bytes());
            len_delimited(1, &v, &mut summary); // Summary.value
        }
        len_delimited(5, &summary, &mut e); // Event.summary
    }
    e
}

/// Frame `data` as one TFRecord.
pub fn tfrecord(data: &[u8]) -> Vec<u8> {
    let len = (data.len() as u64).to_le_bytes();
    let mut out = Vec::with_capacity(data.len() + 16);
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc(data).to_le_bytes());
    out
}

impl TbWriter {
    /// A new event file in `dir`.
    pub fn create(dir: &Path) -> Result<TbWriter> {
        std::fs::create_dir_all(dir).map_err(|e| RuntimeError::file(dir, e))?;
        let host = std::fs::read_to_string("/etc/hostname").map(|s| s.trim().to_string()).unwrap_or("pednav".into());
        let path = dir.join(format!("events.out.tfevents.{}.{host}.{}", wall_time() as u64, std::process::id()));
        let file = File::create(&path).map_err(|e| RuntimeError::file(&path, e))?;
        let mut w = TbWriter { file: AppendFile::new(file, path) };
        w.file.append(tfrecord(&event(0, Some("brain.Event:2"), &[])));
        Ok(w)
    }

    /// Write scalars at `step` (waiting in memory when the disk does not take them).
    pub fn scalars(&mut self, step: u64, values: &[(&str, f64)]) {
        self.file.append(tfrecord(&event(step, None, values)));
    }

    /// The event file.
    pub fn path(&self) -> &Path {
        &self.file.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_matches_the_published_check_value() {
        // The CRC-32C check value of "123456789" (RFC 3720, appendix B.4).
        assert_eq!(crc32c::crc32c(b"123456789"), 0xE306_9283);
    }

    #[test]
    fn records_are_framed_and_scalars_encoded() {
        let data = event(7, None, &[("loss", 0.5)]);
        let rec = tfrecord(&data);
        assert_eq!(u64::from_le_bytes(rec[..8].try_into().unwrap()) as usize, data.len());
        assert_eq!(&rec[12..12 + data.len()], &data[..]);
        let tail = u32::from_le_bytes(rec[rec.len() - 4..].try_into().unwrap());
        assert_eq!(tail, masked_crc(&data));
        // step 7 as a varint right after the 9-byte wall time.
        assert_eq!(&data[9..11], &[0x10, 7]);
        // Summary → Value → tag "loss", simple_value 0.5.
        let needle = [&[0x0a, 4][..], b"loss", &[0x15], &0.5f32.to_le_bytes()].concat();
        assert!(data.windows(needle.len()).any(|w| w == needle), "{data:?}");
    }

    #[test]
    fn rows_the_disk_refuses_wait_in_memory_and_arrive_whole_once_it_takes_them() {
        let dir = std::env::temp_dir().join(format!("pednav-metrics-full-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut m = Metrics::open(&dir, &dir.join("tb"), "x").unwrap();
        m.log(1, &[("a", 1.0)]).unwrap();
        assert!(m.failing().is_none());
        m.inject_disk_full(2);
        m.log(2, &[("a", 2.0)]).unwrap();
        m.log(3, &[("a", 3.0)]).unwrap();
        let f = m.failing().expect("rows are waiting");
        assert_eq!((f.waiting, f.path), (2, dir.join("x.csv").as_path()));
        assert!(crate::generations::is_disk_full(f.error), "{}", f.error);
        // Half-written rows were cut off again: the file holds whole rows only.
        assert_eq!(std::fs::read_to_string(dir.join("x.csv")).unwrap(), "step,a\n1,1\n");
        // The disk takes writes again: everything waiting arrives, in order.
        m.log(4, &[("a", 4.0)]).unwrap();
        assert!(m.failing().is_none());
        assert_eq!(std::fs::read_to_string(dir.join("x.csv")).unwrap(), "step,a\n1,1\n2,2\n3,3\n4,4\n");
        // TensorBoard too: its file is a whole sequence of records (header + 4 rows).
        let tb = std::fs::read(m.tb.path()).unwrap();
        let (mut at, mut records) = (0, 0);
        while at < tb.len() {
            let len = u64::from_le_bytes(tb[at..at + 8].try_into().unwrap()) as usize;
            at += 12 + len + 4;
            records += 1;
        }
        assert_eq!((at, records), (tb.len(), 5));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn memory_for_waiting_records_is_bounded_and_the_overflow_counted() {
        let dir = std::env::temp_dir().join(format!("pednav-metrics-cap-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut f = AppendFile::open(&dir.join("log.csv")).unwrap();
        f.inject = MAX_WAITING + 10;
        for i in 0..MAX_WAITING + 5 {
            f.append(format!("{i}\n").into_bytes());
        }
        let failure = f.failure().expect("failing");
        assert_eq!((failure.waiting, failure.dropped), (MAX_WAITING, 5));
        // Once the disk takes writes, the kept records arrive in order, whole.
        f.inject = 0;
        f.append(b"last\n".to_vec());
        assert!(f.failure().is_none());
        let text = std::fs::read_to_string(dir.join("log.csv")).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), MAX_WAITING + 1);
        assert_eq!(
            (lines[0], lines[MAX_WAITING - 1], lines[MAX_WAITING]),
            ("0", &*format!("{}", MAX_WAITING - 1), "last")
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn csv_keeps_its_columns_across_reopen() {
        let dir = std::env::temp_dir().join(format!("pednav-metrics-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut m = Metrics::open(&dir, &dir.join("tb"), "x").unwrap();
        m.log(1, &[("a", 1.0), ("b", 2.0)]).unwrap();
        drop(m);
        let mut m = Metrics::open(&dir, &dir.join("tb"), "x").unwrap();
        m.log(2, &[("b", 3.0)]).unwrap();
        m.log_optional(3, &[("a", None), ("b", Some(4.0))]).unwrap();
        let text = std::fs::read_to_string(dir.join("x.csv")).unwrap();
        assert_eq!(text, "step,a,b\n1,1,2\n2,,3\n3,,4\n");
        let _ = std::fs::remove_dir_all(&dir);
        // A first row whose values do not exist yet still fixes every column.
        std::fs::create_dir_all(&dir).unwrap();
        let mut m = Metrics::open(&dir, &dir.join("tb"), "y").unwrap();
        m.log_optional(1, &[("fit", None), ("n", Some(1.0))]).unwrap();
        m.log_optional(2, &[("fit", Some(0.5)), ("n", Some(2.0))]).unwrap();
        let text = std::fs::read_to_string(dir.join("y.csv")).unwrap();
        assert_eq!(text, "step,fit,n\n1,,1\n2,0.5,2\n");
        assert!(!text.contains("NaN"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
