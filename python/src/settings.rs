//! Simulator settings from Python keyword arguments, read by pednav-sim's own schema.
//!
//! A run config's `[sim]` table, and `--set sim.<field>=<value>` on the command lines,
//! hand the simulator TOML values that `SimConfig`'s serde derive reads (refusing
//! unknown fields, with `SimConfig`'s defaults for the rest) and that
//! `SimConfig::validate` checks. Here each Python keyword's value becomes the TOML value
//! it stands for — a bool, an integer, a float or a string; nothing else is a setting —
//! and goes into a table of the defaults, which the same derive and the same check then
//! read. So the package accepts exactly the settings a run config accepts, and refuses
//! the others with the Rust message, prefixed by the setting's name.
//!
//! Invariant: no field name, range or default is written in this module; all of them
//! are `SimConfig`'s (and the backend's names `BackendChoice`'s).

use pednav_sim::{BackendChoice, SimConfig};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyString};

use crate::{PednavError, sim_error};

/// The simulator settings `settings` (field name → value) over `SimConfig`'s defaults,
/// read by `SimConfig`'s schema and checked by `SimConfig::validate`.
pub fn sim_config(settings: Option<&Bound<'_, PyDict>>) -> PyResult<SimConfig> {
    let mut table = toml::Table::try_from(SimConfig::default()).expect("the default SimConfig is a TOML table");
    if let Some(settings) = settings {
        for (key, value) in settings.iter() {
            let key: String = key.extract()?;
            let value = toml_value(&value).map_err(|message| setting_error(&key, &message))?;
            table.insert(key.clone(), value);
            // Read after each setting, so that a name or value the schema refuses is
            // reported under the setting that brought it.
            table.clone().try_into::<SimConfig>().map_err(|e| setting_error(&key, &e.to_string()))?;
        }
    }
    let config: SimConfig = table.try_into().map_err(|e| PednavError::new_err(e.to_string().trim_end().to_owned()))?;
    config.validate().map_err(sim_error)?;
    Ok(config)
}

/// The settings of `config` as a dict of field name → value (bool, int, float or str),
/// as a run directory's `config.toml` writes its `[sim]` table.
pub fn settings_dict<'py>(py: Python<'py>, config: &SimConfig) -> PyResult<Bound<'py, PyDict>> {
    let table = toml::Table::try_from(config).expect("a SimConfig is a TOML table");
    let dict = PyDict::new(py);
    for (key, value) in &table {
        dict.set_item(key, python_value(py, value)?)?;
    }
    Ok(dict)
}

/// The graphics backend named `name` (`auto`, `vulkan` or `gl`), or, with `None`, the
/// one the `PEDNAV_BACKEND` environment variable names, as every pednav command chooses it.
pub fn backend(name: Option<&str>) -> PyResult<BackendChoice> {
    match name {
        None => BackendChoice::from_env().map_err(PednavError::new_err),
        Some(name) => toml::Value::String(name.to_owned())
            .try_into::<BackendChoice>()
            .map_err(|e| PednavError::new_err(format!("backend `{name}`: {}", e.to_string().trim_end()))),
    }
}

fn setting_error(key: &str, message: &str) -> PyErr {
    PednavError::new_err(format!("simulator setting `{key}`: {}", message.trim_end()))
}

/// The TOML value a Python value stands for. `bool` is tried before the integers
/// (Python's `True` is also an int) and NumPy scalars are read through their
/// `__index__` and `__float__`.
fn toml_value(value: &Bound<'_, PyAny>) -> Result<toml::Value, String> {
    if let Ok(flag) = value.extract::<bool>() {
        return Ok(toml::Value::Boolean(flag));
    }
    if value.is_instance_of::<PyString>() {
        return value.extract::<String>().map(toml::Value::String).map_err(|e| e.to_string());
    }
    if value.is_instance_of::<PyFloat>() {
        return value.extract::<f64>().map(toml::Value::Float).map_err(|e| e.to_string());
    }
    if let Ok(integer) = value.extract::<i64>() {
        return Ok(toml::Value::Integer(integer));
    }
    if let Ok(number) = value.extract::<f64>() {
        return Ok(toml::Value::Float(number));
    }
    let shown = value.repr().map(|r| r.to_string()).unwrap_or_else(|_| "the value".to_owned());
    Err(format!("{shown} is not a bool, an integer, a float or a string"))
}

fn python_value<'py>(py: Python<'py>, value: &toml::Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match value {
        toml::Value::Boolean(flag) => PyBool::new(py, *flag).to_owned().into_any(),
        toml::Value::Integer(integer) => integer.into_pyobject(py)?.into_any(),
        toml::Value::Float(number) => PyFloat::new(py, *number).into_any(),
        toml::Value::String(text) => PyString::new(py, text).into_any(),
        other => PyString::new(py, &other.to_string()).into_any(),
    })
}
