/* C helpers of the scalar route (the Python back end for Mitsuba's scalar variants, msx/plugin/scalar.py).
 *
 * Compiled into the cffi API-mode extension msx._native together with the Rust core (see setup.py and
 * docs/building.md). They take and return plain floats and flat structs, so that each Python-side BSDF call
 * crosses cffi exactly once with cheap argument conversion (floats instead of building MsxVec3 structs).
 *
 * setup.py derives the cffi declarations (cdef) from this file with the same function that reads
 * include/msx.h: comments and preprocessor lines are dropped, the rest must stay plain C declarations that
 * cffi can parse (typedefs, structs, prototypes; no macros, no inline bodies).
 */
#ifndef MSXPY_HELPERS_H
#define MSXPY_HELPERS_H

#include "msx.h"

/* Per-instance state: the BSDF handle and the cached material (used when no texture varies). */
typedef struct MsxpyInst {
    const MsxBsdf *bsdf;
    MsxMaterial mat;
} MsxpyInst;

/* Flat result structs: one cdata attribute access per value. */
typedef struct MsxpyEvalPdf {
    float v0, v1, v2, v3, pdf;
} MsxpyEvalPdf;

typedef struct MsxpySample {
    float x, y, z, pdf, w0, w1, w2, w3;
    uint32_t valid;
} MsxpySample;

/* `m` is the material evaluated at the hit, or NULL for the cached one (s->mat). The key of an evaluation
   comes from where it happens (hit position p and uv, see msx_call_key), so estimates never depend on the
   order of the calls. */
MsxpyEvalPdf msxpy_eval_pdf(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
                            float wox, float woy, float woz, float px, float py, float pz, float u, float v);
MsxpyEvalPdf msxpy_eval(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
                        float wox, float woy, float woz, float px, float py, float pz, float u, float v);
float msxpy_pdf(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
                float wox, float woy, float woz);
MsxpySample msxpy_sample(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
                         float s1, float u, float v);

#endif /* MSXPY_HELPERS_H */
