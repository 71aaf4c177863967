/* C helpers of the scalar route: declarations and purpose in msxpy_helpers.h. */
#include "msxpy_helpers.h"

static MsxpyEvalPdf pack_eval_pdf(MsxEvalPdf r) {
    MsxpyEvalPdf o = { r.value.v[0], r.value.v[1], r.value.v[2], r.value.v[3], r.pdf };
    return o;
}

static MsxpyEvalPdf pack_eval(MsxSpectrum r) {
    MsxpyEvalPdf o = { r.v[0], r.v[1], r.v[2], r.v[3], 0.0f };
    return o;
}

static MsxpySample pack_sample(MsxSample r) {
    MsxpySample o = { r.wo.x, r.wo.y, r.wo.z, r.pdf,
                      r.weight.v[0], r.weight.v[1], r.weight.v[2], r.weight.v[3], r.valid };
    return o;
}

MsxpyEvalPdf msxpy_eval_pdf(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
                            float wox, float woy, float woz, float px, float py, float pz, float u, float v) {
    MsxVec3 wi = { wix, wiy, wiz }, wo = { wox, woy, woz };
    return pack_eval_pdf(msx_eval_pdf(s->bsdf, m ? m : &s->mat, wi, wo, msx_call_key(px, py, pz, u, v)));
}

MsxpyEvalPdf msxpy_eval(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
                        float wox, float woy, float woz, float px, float py, float pz, float u, float v) {
    MsxVec3 wi = { wix, wiy, wiz }, wo = { wox, woy, woz };
    return pack_eval(msx_eval(s->bsdf, m ? m : &s->mat, wi, wo, msx_call_key(px, py, pz, u, v)));
}

float msxpy_pdf(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
                float wox, float woy, float woz) {
    MsxVec3 wi = { wix, wiy, wiz }, wo = { wox, woy, woz };
    return msx_pdf(s->bsdf, m ? m : &s->mat, wi, wo);
}

MsxpySample msxpy_sample(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
                         float s1, float u, float v) {
    MsxVec3 wi = { wix, wiy, wiz };
    return pack_sample(msx_sample(s->bsdf, m ? m : &s->mat, wi, s1, u, v));
}
