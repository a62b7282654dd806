//! Metrics of one process: CSV rows and TensorBoard scalars side by side.
//!
//! Invariants: the CSV's columns are fixed by its header (the first row written,
//! or the existing header when a resumed process appends); every row is flushed
//! when written, so a killed process loses at most the row being written. The
//! TensorBoard file is a TFRecord stream of `Event` protos (wall time, step,
//! `simple_value` summaries), each record framed by masked CRC-32C checksums as
//! TensorBoard's reader expects; a resumed process starts a new event file.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use crate::error::{Result, RuntimeError};

/// CSV + TensorBoard writer for one process.
pub struct Metrics {
    csv: File,
    csv_path: PathBuf,
    columns: Vec<String>,
    tb: TbWriter,
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
        let csv = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&csv_path)
            .map_err(|e| RuntimeError::file(&csv_path, e))?;
        let tb = TbWriter::create(&tb_dir.join(name))?;
        Ok(Metrics { csv, csv_path, columns, tb })
    }

    /// Write one row: `step` plus named values. The first row fixes the columns;
    /// later rows must name the same values (missing ones are left empty).
    pub fn log(&mut self, step: u64, values: &[(&str, f64)]) -> Result<()> {
        let values: Vec<(&str, Option<f64>)> = values.iter().map(|&(k, v)| (k, Some(v))).collect();
        self.log_optional(step, &values)
    }

    /// [`Metrics::log`] with values that may not exist yet (a statistic before its
    /// first sample, a fit before the first fit): a `None` still names its column, its
    /// CSV cell stays empty and TensorBoard gets no point — never a placeholder NaN.
    pub fn log_optional(&mut self, step: u64, values: &[(&str, Option<f64>)]) -> Result<()> {
        if self.columns.is_empty() {
            self.columns =
                std::iter::once("step".to_string()).chain(values.iter().map(|(k, _)| k.to_string())).collect();
            writeln!(self.csv, "{}", self.columns.join(",")).map_err(|e| RuntimeError::file(&self.csv_path, e))?;
        }
        let mut row = Vec::with_capacity(self.columns.len());
        for c in &self.columns {
            if c == "step" {
                row.push(step.to_string());
            } else {
                let value = values.iter().find(|(k, _)| k == c).and_then(|(_, v)| *v);
                row.push(value.map(|v| format!("{v}")).unwrap_or_default());
            }
        }
        writeln!(self.csv, "{}", row.join(",")).map_err(|e| RuntimeError::file(&self.csv_path, e))?;
        self.csv.flush().map_err(|e| RuntimeError::file(&self.csv_path, e))?;
        let present: Vec<(&str, f64)> = values.iter().filter_map(|&(k, v)| Some((k, v?))).collect();
        self.tb.scalars(step, &present)
    }
}

/// A TensorBoard event-file writer (scalars only).
pub struct TbWriter {
    file: File,
    path: PathBuf,
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
        let mut w = TbWriter { file, path };
        w.write(&event(0, Some("brain.Event:2"), &[]))?;
        Ok(w)
    }

    fn write(&mut self, data: &[u8]) -> Result<()> {
        self.file.write_all(&tfrecord(data)).map_err(|e| RuntimeError::file(&self.path, e))?;
        self.file.flush().map_err(|e| RuntimeError::file(&self.path, e))
    }

    /// Write scalars at `step`.
    pub fn scalars(&mut self, step: u64, values: &[(&str, f64)]) -> Result<()> {
        self.write(&event(step, None, values))
    }

    /// The event file.
    pub fn path(&self) -> &Path {
        &self.path
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
