//! The recording format: a directory with `frames.jsonl` (one JSON object per frame) and the frame
//! files beside it. Used by `render`, replay, record and all test data.
//!
//! Each line holds at least `"file"` (path relative to the directory) and `"t"` (seconds); optional
//! `"pose"` (`{"x", "y", "theta"}`: the robot's ground pose in the field frame, metres and radians),
//! `"camera"` (`{"height", "pitch", "roll", "head_yaw"}`, metres and radians) and, for raw `.yuyv`
//! frames, `"width"` and `"height"`. Frame files are PNG or JPEG (RGB) or raw packed YUYV.
//! Unknown keys are ignored, so recordings can carry more.

use std::fs::{self, File, OpenOptions};
use std::io::{BufRead, BufReader, LineWriter, Write};
use std::path::{Component, Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::frame::{Frame, FrameError, YuyvImage};
use crate::geometry::{CameraPose, FieldPose};

/// Name of the index file inside a recording directory.
pub const INDEX_FILE: &str = "frames.jsonl";

/// What went wrong reading or writing a recording.
#[derive(Debug, Error)]
pub enum RecordingError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A line of `frames.jsonl` is not a valid frame record.
    #[error("{path}:{line}: {reason}")]
    BadRecord {
        /// The index file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// A frame file could not be decoded.
    #[error("frame {path}: {reason}")]
    BadFrame {
        /// The frame file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// The recording holds no frames.
    #[error("{} holds no frames", .directory.display())]
    Empty {
        /// The recording directory.
        directory: PathBuf,
    },
    /// Writing would overwrite an existing recording.
    #[error("{0} already holds a recording: choose another directory or remove it first")]
    AlreadyExists(PathBuf),
}

/// How a frame file is stored, from its extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameFormat {
    /// PNG, RGB.
    Png,
    /// JPEG, RGB.
    Jpeg,
    /// Raw packed YUYV 4:2:2, size given by the record's `width` and `height`.
    Yuyv,
}

impl FrameFormat {
    /// The format a file name's extension implies.
    pub fn from_path(path: &Path) -> Option<Self> {
        let extension = path.extension()?.to_str()?.to_ascii_lowercase();
        match extension.as_str() {
            "png" => Some(Self::Png),
            "jpg" | "jpeg" => Some(Self::Jpeg),
            "yuyv" => Some(Self::Yuyv),
            _ => None,
        }
    }

    /// The file extension written for this format.
    pub fn extension(self) -> &'static str {
        match self {
            Self::Png => "png",
            Self::Jpeg => "jpg",
            Self::Yuyv => "yuyv",
        }
    }
}

/// One line of `frames.jsonl`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    /// Frame file, relative to the recording directory.
    pub file: String,
    /// Capture time in seconds.
    pub t: f64,
    /// The robot's true ground pose, if known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose: Option<FieldPose>,
    /// The camera's pose on the robot, if known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraPose>,
    /// Image width in pixels (required for `.yuyv`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width: Option<u32>,
    /// Image height in pixels (required for `.yuyv`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height: Option<u32>,
}

impl FrameRecord {
    /// Parses and checks one line of `frames.jsonl`.
    pub fn parse_line(line: &str) -> Result<Self, String> {
        let record: FrameRecord = serde_json::from_str(line).map_err(|error| error.to_string())?;
        record.validate()?;
        Ok(record)
    }

    /// Checks what serde cannot: a usable relative path, a known format, a finite time, and a size for
    /// raw frames.
    fn validate(&self) -> Result<FrameFormat, String> {
        let path = Path::new(&self.file);
        if self.file.is_empty()
            || path.components().any(|component| !matches!(component, Component::Normal(_)))
        {
            return Err(format!(
                "\"file\" must be a relative path inside the recording without '..', found {:?}",
                self.file
            ));
        }
        let format = FrameFormat::from_path(path).ok_or_else(|| {
            format!("\"file\" {:?} has an unknown extension: expected .png, .jpg, .jpeg or .yuyv", self.file)
        })?;
        if !self.t.is_finite() {
            return Err(format!("\"t\" must be a finite number of seconds, found {}", self.t));
        }
        if format == FrameFormat::Yuyv && (self.width.is_none() || self.height.is_none()) {
            return Err(format!("raw frame {:?} needs \"width\" and \"height\"", self.file));
        }
        Ok(format)
    }
}

/// A recording directory opened for reading.
#[derive(Clone, Debug)]
pub struct Recording {
    directory: PathBuf,
    records: Vec<FrameRecord>,
}

impl Recording {
    /// Whether `path` is a recording directory (it holds `frames.jsonl`), not a single frame's file.
    pub fn is_at(path: &Path) -> bool {
        path.join(INDEX_FILE).is_file()
    }

    /// Reads and checks `frames.jsonl` (blank lines are skipped). Frame files are read on demand.
    pub fn open(directory: &Path) -> Result<Self, RecordingError> {
        let index = directory.join(INDEX_FILE);
        let file = File::open(&index).map_err(|source| RecordingError::Io { path: index.clone(), source })?;
        let mut records = Vec::new();
        for (number, line) in BufReader::new(file).lines().enumerate() {
            let line = line.map_err(|source| RecordingError::Io { path: index.clone(), source })?;
            if line.trim().is_empty() {
                continue;
            }
            let bad =
                |reason: String| RecordingError::BadRecord { path: index.clone(), line: number + 1, reason };
            records.push(FrameRecord::parse_line(&line).map_err(bad)?);
        }
        Ok(Self { directory: directory.to_path_buf(), records })
    }

    /// The directory.
    pub fn directory(&self) -> &Path {
        &self.directory
    }

    /// The frame records, in file order.
    pub fn records(&self) -> &[FrameRecord] {
        &self.records
    }

    /// Reads and decodes one frame's file.
    pub fn load_frame(&self, record: &FrameRecord) -> Result<Frame, RecordingError> {
        let path = self.directory.join(&record.file);
        let bad = |reason: String| RecordingError::BadFrame { path: path.clone(), reason };
        let format = record.validate().map_err(bad)?;
        let bytes = fs::read(&path).map_err(|source| RecordingError::Io { path: path.clone(), source })?;
        let frame = match format {
            FrameFormat::Png | FrameFormat::Jpeg => {
                let image = image::load_from_memory(&bytes).map_err(|error| bad(error.to_string()))?;
                Frame::Rgb(image.into_rgb8())
            }
            FrameFormat::Yuyv => {
                let (width, height) = (record.width.unwrap_or(0), record.height.unwrap_or(0));
                Frame::Yuyv(
                    YuyvImage::new(width, height, bytes)
                        .map_err(|error: FrameError| bad(error.to_string()))?,
                )
            }
        };
        if let (Some(width), Some(height)) = (record.width, record.height)
            && frame.dimensions() != (width, height)
        {
            let (found_width, found_height) = frame.dimensions();
            return Err(bad(format!(
                "the record says {width}x{height} but the file holds {found_width}x{found_height}"
            )));
        }
        Ok(frame)
    }
}

/// Writes a new recording: frame files plus `frames.jsonl`, one line per frame as it is added.
pub struct RecordingWriter {
    directory: PathBuf,
    index: LineWriter<File>,
}

impl RecordingWriter {
    /// Creates the directory (if needed) and a new `frames.jsonl`; refuses to overwrite one.
    pub fn create(directory: &Path) -> Result<Self, RecordingError> {
        fs::create_dir_all(directory)
            .map_err(|source| RecordingError::Io { path: directory.to_path_buf(), source })?;
        let path = directory.join(INDEX_FILE);
        let file = OpenOptions::new().write(true).create_new(true).open(&path).map_err(|source| {
            if source.kind() == std::io::ErrorKind::AlreadyExists {
                RecordingError::AlreadyExists(directory.to_path_buf())
            } else {
                RecordingError::Io { path: path.clone(), source }
            }
        })?;
        Ok(Self { directory: directory.to_path_buf(), index: LineWriter::new(file) })
    }

    /// The directory being written.
    pub fn directory(&self) -> &Path {
        &self.directory
    }

    /// Encodes `frame` into `record.file` (format from its extension) and appends the record.
    pub fn write_frame(&mut self, record: &FrameRecord, frame: &Frame) -> Result<(), RecordingError> {
        write_frame_file(&self.directory, record, frame)?;
        self.append(record)
    }

    /// Appends a record whose frame file is already in place.
    pub fn append(&mut self, record: &FrameRecord) -> Result<(), RecordingError> {
        let path = self.directory.join(INDEX_FILE);
        let line = serde_json::to_string(record).expect("frame records serialise");
        writeln!(self.index, "{line}").map_err(|source| RecordingError::Io { path, source })
    }
}

/// Encodes `frame` into the file `record.file` names, inside `directory`. Safe to call from several
/// threads for different records.
pub fn write_frame_file(directory: &Path, record: &FrameRecord, frame: &Frame) -> Result<(), RecordingError> {
    let path = directory.join(&record.file);
    let bad = |reason: String| RecordingError::BadFrame { path: path.clone(), reason };
    let format = record.validate().map_err(bad)?;
    let io = |source| RecordingError::Io { path: path.clone(), source };
    match (format, frame) {
        (FrameFormat::Yuyv, Frame::Yuyv(yuyv)) => fs::write(&path, yuyv.as_bytes()).map_err(io),
        (FrameFormat::Yuyv, Frame::Rgb(rgb)) => {
            let yuyv = YuyvImage::from_rgb(rgb).map_err(|error| bad(error.to_string()))?;
            fs::write(&path, yuyv.as_bytes()).map_err(io)
        }
        (FrameFormat::Png | FrameFormat::Jpeg, frame) => {
            frame.to_rgb().save(&path).map_err(|error| bad(error.to_string()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{Rgb, RgbImage};

    fn record(file: &str) -> FrameRecord {
        FrameRecord {
            file: file.into(),
            t: 0.5,
            pose: Some(FieldPose::new(1.0, -2.0, 0.3).unwrap()),
            camera: Some(CameraPose::new(0.5, 0.1, 0.0, 0.0).unwrap()),
            width: Some(4),
            height: Some(2),
        }
    }

    #[test]
    fn writes_and_reads_back_png_and_yuyv_frames() {
        let dir = tempfile::tempdir().unwrap();
        let image = RgbImage::from_pixel(4, 2, Rgb([40, 160, 60]));
        let mut writer = RecordingWriter::create(dir.path()).unwrap();
        writer.write_frame(&record("a.png"), &Frame::Rgb(image.clone())).unwrap();
        writer.write_frame(&record("b.yuyv"), &Frame::Rgb(image.clone())).unwrap();
        drop(writer);

        let recording = Recording::open(dir.path()).unwrap();
        assert_eq!(recording.records().len(), 2);
        assert_eq!(recording.records()[0], record("a.png"));
        assert_eq!(recording.load_frame(&recording.records()[0]).unwrap(), Frame::Rgb(image));
        let raw = recording.load_frame(&recording.records()[1]).unwrap();
        assert!(matches!(raw, Frame::Yuyv(_)));
        assert_eq!(raw.dimensions(), (4, 2));
    }

    #[test]
    fn refuses_to_overwrite_a_recording() {
        let dir = tempfile::tempdir().unwrap();
        drop(RecordingWriter::create(dir.path()).unwrap());
        let error = RecordingWriter::create(dir.path()).err().unwrap();
        assert!(
            error
                .to_string()
                .ends_with("already holds a recording: choose another directory or remove it first")
        );
    }

    #[test]
    fn unknown_keys_are_ignored_and_optional_keys_may_be_missing() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(dir.path().join(INDEX_FILE), "{\"file\": \"x.png\", \"t\": 1.0, \"exposure\": 3}\n\n")
            .unwrap();
        let recording = Recording::open(dir.path()).unwrap();
        assert_eq!(recording.records()[0].pose, None);
    }

    #[test]
    fn bad_lines_name_the_line_and_the_problem() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            ("{\"file\": \"x.png\"}", "missing field `t`"),
            ("{\"file\": \"../x.png\", \"t\": 0}", "without '..'"),
            ("{\"file\": \"/etc/x.png\", \"t\": 0}", "relative path"),
            ("{\"file\": \"x.bmp\", \"t\": 0}", "unknown extension"),
            ("{\"file\": \"x.yuyv\", \"t\": 0}", "needs \\\"width\\\" and \\\"height\\\""),
            ("{\"file\": \"x.png\", \"t\": 0, \"pose\": {\"x\": 1, \"y\": 0}}", "missing field `theta`"),
            ("not json", "expected ident"),
        ];
        for (line, expected) in cases {
            fs::write(dir.path().join(INDEX_FILE), format!("{{\"file\": \"ok.png\", \"t\": 0}}\n{line}\n"))
                .unwrap();
            let error = Recording::open(dir.path()).unwrap_err().to_string();
            assert!(error.contains("frames.jsonl:2: "), "{error}");
            assert!(error.contains(expected.replace("\\\"", "\"").as_str()), "{line}: {error}");
        }
    }

    #[test]
    fn truncated_and_corrupt_frames_give_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(dir.path().join("short.yuyv"), [0u8; 10]).unwrap();
        fs::write(dir.path().join("junk.png"), b"not a png").unwrap();
        fs::write(
            dir.path().join(INDEX_FILE),
            "{\"file\": \"short.yuyv\", \"t\": 0, \"width\": 4, \"height\": 2}\n{\"file\": \"junk.png\", \"t\": 0}\n{\"file\": \"gone.png\", \"t\": 0}\n",
        )
        .unwrap();
        let recording = Recording::open(dir.path()).unwrap();
        let errors: Vec<String> =
            recording.records().iter().map(|r| recording.load_frame(r).unwrap_err().to_string()).collect();
        assert!(errors[0].contains("needs 16 bytes, got 10"), "{}", errors[0]);
        assert!(errors[1].contains("junk.png"), "{}", errors[1]);
        assert!(errors[2].contains("gone.png"), "{}", errors[2]);
    }

    #[test]
    fn missing_index_is_an_io_error_naming_the_file() {
        let error = Recording::open(Path::new("/nonexistent/recording")).unwrap_err().to_string();
        assert!(error.starts_with("/nonexistent/recording/frames.jsonl: "), "{error}");
    }
}
