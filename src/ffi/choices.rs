//! The table of names for C: every choice of the configuration parameters
//! (surface, distribution, model, estimator, mis_density) with its name, its code and, for
//! a model, what it supports. The rows are those of `src/config.rs` (`SURFACES`,
//! `DISTRIBUTIONS`, `MODELS`, `ESTIMATORS`); the Python package
//! (`mitsuba_plugin/msx/plugin/parameters.py`) and the native plugin
//! (`native/msx_mitsuba.cpp`) build their choice lists from these functions.

use super::output::caught_panic;
use super::{MSX_ERR_INVALID_PARAMETER, MSX_ERR_NULL_POINTER, MSX_ERR_PANIC, MSX_OK};
use crate::config::{Choice, Distribution, Estimator, MisDensity, Model, ModelInfo, Surface, MODELS};
use std::ffi::CString;
use std::os::raw::c_char;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::OnceLock;

/// The parameters `msx_choice` describes (its `parameter` argument).
pub const MSX_CHOICE_SURFACE: u32 = 0;
pub const MSX_CHOICE_DISTRIBUTION: u32 = 1;
pub const MSX_CHOICE_MODEL: u32 = 2;
pub const MSX_CHOICE_ESTIMATOR: u32 = 3;
/// The conductor walks' MIS densities (code 0 in `MsxParams::mis_density`, the
/// default, is not a row).
pub const MSX_CHOICE_MIS_DENSITY: u32 = 4;
/// The number of parameters: MSX_CHOICE_* < MSX_CHOICE_PARAMETERS.
pub const MSX_CHOICE_PARAMETERS: u32 = 5;

/// `MsxChoice::flags` of a model: `eval` is one unbiased estimate of a random
/// walk (else a deterministic closed form).
pub const MSX_FLAG_RANDOM_WALK: u32 = 1;
/// `MsxChoice::flags` of a model: evaluating a range of scattering orders gives
/// the model's own value per order (else its whole value counts as order 1).
pub const MSX_FLAG_PER_ORDER: u32 = 2;
/// `MsxChoice::flags` of a model: it estimates the Smith microsurface's
/// multiple-scattering BSDF without approximation (the reference).
pub const MSX_FLAG_EXACT: u32 = 4;

/// One choice of a parameter. The fields after `code` describe a model and
/// are 0 for the other parameters.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MsxChoice {
    /// Its name in scenes: a static NUL-terminated string, never freed
    /// ("" when `msx_choice` fails)
    pub name: *const c_char,
    /// Its code (MSX_SURFACE_*, MSX_DISTRIBUTION_*, MSX_MODEL_*, MSX_ESTIMATOR_*)
    pub code: u32,
    /// Model: MSX_FLAG_* bits
    pub flags: u32,
    /// Model: bit (1 << MSX_SURFACE_*) set for every surface it supports
    pub surfaces: u32,
    /// Model: the surfaces (same bits) on which it accepts MSX_ESTIMATOR_BDPT
    pub bdpt_surfaces: u32,
    /// Model: bit (1 << MSX_DISTRIBUTION_*) set for every distribution it is defined for
    pub distributions: u32,
    /// Model: the code of the model whose walk it runs (its own code; `auto`: `correlated`'s)
    pub runs: u32,
}

const EMPTY: &[u8] = b"\0";

impl MsxChoice {
    fn empty() -> Self {
        MsxChoice { name: EMPTY.as_ptr() as *const c_char, code: 0, flags: 0, surfaces: 0, bdpt_surfaces: 0, distributions: 0, runs: 0 }
    }
}

/// A row as it is kept: the name owned as a C string (the `MsxChoice`
/// handed out points into it; it lives as long as the process).
struct Row {
    /// Owns the string `choice.name` points into.
    _name: CString,
    choice: MsxChoice,
}

// SAFETY: `choice.name` only ever points into `name` or at `EMPTY`, both
// immutable for the life of the process.
unsafe impl Send for Row {}
unsafe impl Sync for Row {}

fn mask<T: Choice>(values: &[T]) -> u32 {
    values.iter().fold(0, |m, v| m | 1u32.checked_shl(v.code()).unwrap_or(0))
}

fn row(name: &'static str, code: u32, model: Option<&ModelInfo>) -> Row {
    let name = CString::new(name).unwrap_or_default();
    let mut choice = MsxChoice { name: name.as_ptr(), code, ..MsxChoice::empty() };
    if let Some(m) = model {
        choice.flags = (m.random_walk as u32 * MSX_FLAG_RANDOM_WALK) | (m.per_order as u32 * MSX_FLAG_PER_ORDER) | (m.exact as u32 * MSX_FLAG_EXACT);
        choice.surfaces = mask(m.surfaces);
        choice.bdpt_surfaces = mask(m.bdpt);
        choice.distributions = mask(m.distributions);
        choice.runs = m.runs.code();
    }
    Row { _name: name, choice }
}

fn rows_of<T: Choice>() -> Vec<Row> {
    T::all().map(|(_, name, code)| row(name, code, None)).collect()
}

/// Per parameter (indexed by MSX_CHOICE_*): its scene name and its rows.
fn table() -> &'static [(&'static str, Vec<Row>)] {
    static TABLE: OnceLock<Vec<(&'static str, Vec<Row>)>> = OnceLock::new();
    TABLE.get_or_init(|| {
        vec![
            (Surface::PARAMETER, rows_of::<Surface>()),
            (Distribution::PARAMETER, rows_of::<Distribution>()),
            (Model::PARAMETER, MODELS.iter().map(|m| row(m.name, m.code, Some(m))).collect()),
            (Estimator::PARAMETER, rows_of::<Estimator>()),
            (MisDensity::PARAMETER, rows_of::<MisDensity>()),
        ]
    })
}

/// How many choices a parameter (MSX_CHOICE_*) has; 0 for an unknown parameter.
#[no_mangle]
pub extern "C" fn msx_choice_count(parameter: u32) -> u32 {
    catch_unwind(|| table().get(parameter as usize).map_or(0, |p| p.1.len() as u32)).unwrap_or_else(|_| {
        caught_panic();
        0
    })
}

/// The scene name of a parameter (MSX_CHOICE_*: "surface", "distribution",
/// "model", "estimator"), a static NUL-terminated string; null for an unknown
/// parameter.
#[no_mangle]
pub extern "C" fn msx_choice_parameter(parameter: u32) -> *const c_char {
    static NAMES: OnceLock<Vec<CString>> = OnceLock::new();
    catch_unwind(|| {
        let names = NAMES.get_or_init(|| table().iter().map(|p| CString::new(p.0).unwrap_or_default()).collect());
        names.get(parameter as usize).map_or(std::ptr::null(), |n| n.as_ptr())
    })
    .unwrap_or_else(|_| {
        caught_panic();
        std::ptr::null()
    })
}

/// Writes the `index`-th choice (0 ≤ index < msx_choice_count(parameter), in
/// the order of the docs) of a parameter (MSX_CHOICE_*) to `*out`.
/// Returns MSX_OK; MSX_ERR_NULL_POINTER if `out` is null;
/// MSX_ERR_INVALID_PARAMETER for an unknown parameter or an index out of
/// range (then `*out` is zeroed, with `name` = "").
#[no_mangle]
pub extern "C" fn msx_choice(parameter: u32, index: u32, out: *mut MsxChoice) -> i32 {
    if out.is_null() {
        return MSX_ERR_NULL_POINTER;
    }
    let result = catch_unwind(AssertUnwindSafe(|| table().get(parameter as usize).and_then(|p| p.1.get(index as usize)).map(|r| r.choice)));
    let (choice, status) = match result {
        Ok(Some(c)) => (c, MSX_OK),
        Ok(None) => (MsxChoice::empty(), MSX_ERR_INVALID_PARAMETER),
        Err(_) => {
            caught_panic();
            (MsxChoice::empty(), MSX_ERR_PANIC)
        }
    };
    // SAFETY: `out` is non-null and points to an MsxChoice the caller owns (the pointer contract).
    unsafe { out.write(choice) };
    status
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{ALL_MODELS, ALL_SURFACES};
    use std::ffi::CStr;

    fn get(parameter: u32, index: u32) -> (i32, MsxChoice) {
        let mut c = MsxChoice::empty();
        let status = msx_choice(parameter, index, &mut c);
        (status, c)
    }

    fn name(c: &MsxChoice) -> &'static str {
        // SAFETY: msx_choice's names are static NUL-terminated strings.
        unsafe { CStr::from_ptr(c.name) }.to_str().unwrap()
    }

    #[test]
    fn every_model_row_reads_back() {
        assert_eq!(msx_choice_count(MSX_CHOICE_MODEL) as usize, ALL_MODELS.len());
        for (i, m) in ALL_MODELS.iter().enumerate() {
            let (status, c) = get(MSX_CHOICE_MODEL, i as u32);
            assert_eq!(status, MSX_OK);
            assert_eq!(name(&c), m.name());
            assert_eq!(c.code, m.code());
            let info = m.info();
            for s in ALL_SURFACES {
                assert_eq!(c.surfaces >> s.code() & 1 == 1, info.surfaces.contains(&s), "{} {:?}", m.name(), s);
                assert_eq!(c.bdpt_surfaces >> s.code() & 1 == 1, info.bdpt.contains(&s), "{} {:?}", m.name(), s);
            }
            assert_eq!(c.flags & MSX_FLAG_RANDOM_WALK != 0, info.random_walk);
            assert_eq!(c.runs, info.runs.code());
        }
    }

    #[test]
    fn bad_parameter_index_and_null_are_refused() {
        assert_eq!(msx_choice_count(MSX_CHOICE_PARAMETERS), 0);
        assert_eq!(msx_choice_count(u32::MAX), 0);
        assert!(msx_choice_parameter(MSX_CHOICE_PARAMETERS).is_null());
        for (parameter, index) in [(MSX_CHOICE_PARAMETERS, 0), (MSX_CHOICE_MODEL, msx_choice_count(MSX_CHOICE_MODEL)), (u32::MAX, u32::MAX)] {
            let (status, c) = get(parameter, index);
            assert_eq!(status, MSX_ERR_INVALID_PARAMETER);
            assert_eq!((name(&c), c.code, c.surfaces), ("", 0, 0));
        }
        assert_eq!(msx_choice(MSX_CHOICE_MODEL, 0, std::ptr::null_mut()), MSX_ERR_NULL_POINTER);
    }

    #[test]
    fn parameters_have_their_scene_names() {
        let names: Vec<_> =
            (0..MSX_CHOICE_PARAMETERS).map(|p| unsafe { CStr::from_ptr(msx_choice_parameter(p)) }.to_str().unwrap().to_string()).collect();
        assert_eq!(names, ["surface", "distribution", "model", "estimator", "mis_density"]);
    }
}
