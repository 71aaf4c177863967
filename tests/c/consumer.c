/*
 * A C consumer of include/msx.h, compiled and linked against the staticlib
 * libmsx.a by tests/c_abi.rs. It proves that the generated header is valid
 * C (built with -std=c99 -pedantic -Werror) and that the ABI behaves as
 * documented when called from C:
 *
 *   - GGX, alpha = 0.5, model "single": eval / pdf / eval_pdf / sample agree
 *     with the closed-form Walter 2007 BRDF computed here in C, with Mitsuba's
 *     separable Smith term G = G1(wi) G1(wo):
 *         f cos(theta_o) = F(wi.h) D(h) G1(wi) G1(wo) / (4 cos(theta_i)),
 *         pdf            = D(h) G1(wi) / (4 cos(theta_i)),
 *     for material "none" (F = 1) and a Cu-like conductor (F from an
 *     independent complex-arithmetic Fresnel written below);
 *   - the error path (invalid model value, null pointers);
 *   - the batched calls with broadcast arrays equal per-call results lane by
 *     lane (lane i uses key + i), for a deterministic and a stochastic model.
 *
 * On success it prints "ok" and exits 0; otherwise it prints "FAIL: ..." lines
 * and exits 1.
 */
#include "msx.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PI_D 3.14159265358979323846

static int failures = 0;

#define CHECK(cond, ...)                                                       \
    do {                                                                       \
        if (!(cond)) {                                                         \
            failures++;                                                        \
            printf("FAIL (%s:%d): ", __FILE__, __LINE__);                      \
            printf(__VA_ARGS__);                                               \
            printf("\n");                                                      \
        }                                                                      \
    } while (0)

/* ------------------------------------------------------------ reference */

typedef struct {
    double x, y, z;
} dvec3;

static dvec3 dir(double theta, double phi) {
    dvec3 v;
    v.x = sin(theta) * cos(phi);
    v.y = sin(theta) * sin(phi);
    v.z = cos(theta);
    return v;
}

static MsxVec3 to_f(dvec3 v) {
    MsxVec3 r;
    r.x = (float)v.x;
    r.y = (float)v.y;
    r.z = (float)v.z;
    return r;
}

/* The reference works from the float directions that the library receives. */
static dvec3 from_f(MsxVec3 v) {
    dvec3 r;
    double len = sqrt((double)v.x * v.x + (double)v.y * v.y + (double)v.z * v.z);
    r.x = v.x / len;
    r.y = v.y / len;
    r.z = v.z / len;
    return r;
}

static double ggx_d(dvec3 h, double alpha) {
    double c2 = h.z * h.z;
    double tan2 = (h.x * h.x + h.y * h.y) / c2;
    double t = 1.0 + tan2 / (alpha * alpha);
    return 1.0 / (PI_D * alpha * alpha * c2 * c2 * t * t);
}

/* Smith G1 of GGX: 2 / (1 + sqrt(1 + alpha^2 tan^2(theta))). */
static double ggx_g1(dvec3 v, double alpha) {
    double tan2 = (v.x * v.x + v.y * v.y) / (v.z * v.z);
    return 2.0 / (1.0 + sqrt(1.0 + alpha * alpha * tan2));
}

/* Complex numbers, written out so that no C99 <complex.h> is needed. */
typedef struct {
    double re, im;
} cplx;

static cplx c_make(double re, double im) {
    cplx r;
    r.re = re;
    r.im = im;
    return r;
}
static cplx c_add(cplx a, cplx b) { return c_make(a.re + b.re, a.im + b.im); }
static cplx c_sub(cplx a, cplx b) { return c_make(a.re - b.re, a.im - b.im); }
static cplx c_mul(cplx a, cplx b) {
    return c_make(a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re);
}
static cplx c_div(cplx a, cplx b) {
    double d = b.re * b.re + b.im * b.im;
    return c_make((a.re * b.re + a.im * b.im) / d, (a.im * b.re - a.re * b.im) / d);
}
static double c_abs2(cplx a) { return a.re * a.re + a.im * a.im; }
static cplx c_sqrt(cplx a) {
    double m = sqrt(sqrt(c_abs2(a)));
    double arg = atan2(a.im, a.re) / 2.0;
    return c_make(m * cos(arg), m * sin(arg));
}

/* Unpolarised Fresnel reflectance of a conductor with IOR n = eta + i k,
 * from the amplitude coefficients r_s and r_p. */
static double fresnel_conductor(double cos_i, double eta, double k) {
    cplx n = c_make(eta, k);
    cplx ci = c_make(cos_i, 0.0);
    cplx sin2 = c_make(1.0 - cos_i * cos_i, 0.0);
    cplx ct = c_sqrt(c_sub(c_make(1.0, 0.0), c_div(sin2, c_mul(n, n))));
    cplx rs = c_div(c_sub(ci, c_mul(n, ct)), c_add(ci, c_mul(n, ct)));
    cplx rp = c_div(c_sub(c_mul(n, ci), ct), c_add(c_mul(n, ci), ct));
    return 0.5 * (c_abs2(rs) + c_abs2(rp));
}

/* f cos(theta_o) per channel and the pdf, closed form (F = 1 if mirror). */
static void reference(MsxVec3 wi_f, MsxVec3 wo_f, double alpha, const MsxMaterial *m, int mirror,
                      double out[3], double *pdf) {
    dvec3 wi = from_f(wi_f), wo = from_f(wo_f), h;
    double len, d, g1i, g1o;
    int c;
    h.x = wi.x + wo.x;
    h.y = wi.y + wo.y;
    h.z = wi.z + wo.z;
    len = sqrt(h.x * h.x + h.y * h.y + h.z * h.z);
    h.x /= len;
    h.y /= len;
    h.z /= len;
    d = ggx_d(h, alpha);
    g1i = ggx_g1(wi, alpha);
    g1o = ggx_g1(wo, alpha);
    for (c = 0; c < 3; c++) {
        double cos_ih = wi.x * h.x + wi.y * h.y + wi.z * h.z;
        double f = mirror ? 1.0 : fresnel_conductor(cos_ih, m->eta[c], m->k[c]);
        out[c] = f * d * g1i * g1o / (4.0 * wi.z);
    }
    *pdf = d * g1i / (4.0 * wi.z);
}

static int close_rel(double got, double want, double rel) {
    return fabs(got - want) <= rel * fabs(want) + 1e-7;
}

static int same_bits(float a, float b) { return memcmp(&a, &b, sizeof a) == 0; }

/* ------------------------------------------------------------ helpers */

static MsxParams make_params(uint32_t model) {
    MsxParams p;
    memset(&p, 0, sizeof p);
    p.surface = MSX_SURFACE_CONDUCTOR;
    p.distribution = MSX_DISTRIBUTION_GGX;
    p.model = model;
    p.estimator = MSX_ESTIMATOR_PT;
    p.max_bounces = 0; /* library default */
    p.channels = 3;
    p.seed = 42;
    return p;
}

static MsxMaterial make_material(double alpha, const float eta[3], const float k[3]) {
    MsxMaterial m;
    int c;
    memset(&m, 0, sizeof m);
    m.alpha_u = (float)alpha;
    m.alpha_v = (float)alpha;
    for (c = 0; c < 4; c++) {
        m.eta[c] = c < 3 ? eta[c] : 0.0f;
        m.k[c] = c < 3 ? k[c] : 1.0f;
        m.specular_reflectance[c] = 1.0f;
    }
    return m;
}

/* ------------------------------------------------------------ tests */

static void test_single_closed_form(const MsxBsdf *bsdf, const MsxMaterial *mat, int mirror, const char *name) {
    const double alpha = 0.5;
    int ti, to, po;
    int checked = 0;
    for (ti = 0; ti < 6; ti++) {
        for (to = 0; to < 6; to++) {
            for (po = 0; po < 4; po++) {
                double theta_i = 0.05 + ti * 0.28; /* up to ~1.45 rad */
                double theta_o = 0.02 + to * 0.29;
                double phi_o = 0.3 + po * 1.7;
                MsxVec3 wi = to_f(dir(theta_i, 0.4));
                MsxVec3 wo = to_f(dir(theta_o, phi_o));
                double want[3], want_pdf;
                MsxSpectrum got;
                MsxEvalPdf ep;
                float pdf;
                int c;
                reference(wi, wo, alpha, mat, mirror, want, &want_pdf);
                got = msx_eval(bsdf, mat, wi, wo, (uint64_t)checked);
                pdf = msx_pdf(bsdf, mat, wi, wo);
                ep = msx_eval_pdf(bsdf, mat, wi, wo, (uint64_t)checked);
                for (c = 0; c < 3; c++) {
                    CHECK(close_rel(got.v[c], want[c], 2e-4), "%s eval ch%d (ti=%d to=%d po=%d): got %.9g want %.9g",
                          name, c, ti, to, po, got.v[c], want[c]);
                    CHECK(same_bits(ep.value.v[c], got.v[c]), "%s eval_pdf value != eval", name);
                }
                CHECK(got.v[3] == 0.0f, "%s channel 4 of a 3-channel BSDF must be 0, got %g", name, got.v[3]);
                CHECK(close_rel(pdf, want_pdf, 2e-4), "%s pdf (ti=%d to=%d po=%d): got %.9g want %.9g", name, ti, to, po,
                      pdf, want_pdf);
                CHECK(same_bits(ep.pdf, pdf), "%s eval_pdf pdf != pdf", name);
                checked++;
            }
        }
    }
    /* Below the horizon: zero. */
    {
        MsxVec3 wi = to_f(dir(0.5, 0.0)), wo = to_f(dir(0.5, 1.0));
        MsxSpectrum s;
        wo.z = -wo.z;
        s = msx_eval(bsdf, mat, wi, wo, 0);
        CHECK(s.v[0] == 0.0f && s.v[1] == 0.0f && s.v[2] == 0.0f, "%s eval below the horizon must be 0", name);
        CHECK(msx_pdf(bsdf, mat, wi, wo) == 0.0f, "%s pdf below the horizon must be 0", name);
    }
}

static void test_single_sample(const MsxBsdf *bsdf, const MsxMaterial *mat, int mirror, const char *name) {
    const double alpha = 0.5;
    int i, j, t;
    for (t = 0; t < 4; t++) {
        MsxVec3 wi = to_f(dir(0.1 + 0.4 * t, 1.1));
        for (i = 0; i < 8; i++) {
            for (j = 0; j < 8; j++) {
                float u = (i + 0.5f) / 8.0f, v = (j + 0.37f) / 8.0f;
                MsxSample s = msx_sample(bsdf, mat, wi, 0.5f, u, v);
                double want[3], want_pdf, len;
                int c;
                if (!s.valid) {
                    /* An invalid sample is all zero. */
                    CHECK(s.pdf == 0.0f && s.weight.v[0] == 0.0f && s.wo.x == 0.0f && s.wo.z == 0.0f,
                          "%s invalid sample must be zero", name);
                    continue;
                }
                len = sqrt((double)s.wo.x * s.wo.x + (double)s.wo.y * s.wo.y + (double)s.wo.z * s.wo.z);
                CHECK(fabs(len - 1.0) < 1e-5, "%s sampled wo not unit (%g)", name, len);
                CHECK(s.wo.z > 0.0f, "%s sampled wo below the horizon", name);
                reference(wi, s.wo, alpha, mat, mirror, want, &want_pdf);
                CHECK(close_rel(s.pdf, want_pdf, 2e-3), "%s sample pdf %.9g != closed form %.9g", name, s.pdf, want_pdf);
                CHECK(close_rel(s.pdf, msx_pdf(bsdf, mat, wi, s.wo), 2e-3), "%s sample pdf %.9g != msx_pdf %.9g", name,
                      s.pdf, msx_pdf(bsdf, mat, wi, s.wo));
                for (c = 0; c < 3; c++) {
                    CHECK(close_rel(s.weight.v[c], want[c] / want_pdf, 2e-3), "%s sample weight ch%d %.9g != %.9g", name,
                          c, s.weight.v[c], want[c] / want_pdf);
                }
            }
        }
    }
}

/* The table of names (msx_choice): every model's name and code, and one past the largest code, which is no
   model. */
static uint32_t test_choices(void) {
    MsxChoice c;
    uint32_t i, n = msx_choice_count(MSX_CHOICE_MODEL), past = 0;
    const char *parameter = msx_choice_parameter(MSX_CHOICE_MODEL);

    CHECK(parameter != NULL && strcmp(parameter, "model") == 0, "msx_choice_parameter(MSX_CHOICE_MODEL)");
    CHECK(n >= 8, "at least the 8 models of the header: %u", (unsigned)n);
    for (i = 0; i < n; i++) {
        CHECK(msx_choice(MSX_CHOICE_MODEL, i, &c) == MSX_OK && c.name != NULL && c.name[0] != 0, "model row %u",
              (unsigned)i);
        if (c.code == MSX_MODEL_SINGLE)
            CHECK(strcmp(c.name, "single") == 0 && (c.surfaces >> MSX_SURFACE_CONDUCTOR & 1), "single's row");
        if (c.code + 1 > past)
            past = c.code + 1;
    }
    CHECK(msx_choice(MSX_CHOICE_MODEL, n, &c) == MSX_ERR_INVALID_PARAMETER && c.name != NULL && c.name[0] == 0,
          "row past the end");
    CHECK(msx_choice(MSX_CHOICE_PARAMETERS, 0, &c) == MSX_ERR_INVALID_PARAMETER, "unknown parameter");
    CHECK(msx_choice(MSX_CHOICE_MODEL, 0, NULL) == MSX_ERR_NULL_POINTER, "null out");
    return past;
}

static void test_errors(void) {
    MsxParams p = make_params(test_choices()); /* not a model */
    MsxBsdf *out = NULL;
    char err[256];
    int32_t rc;

    memset(err, 'x', sizeof err);
    rc = msx_bsdf_new(&p, &out, err, sizeof err);
    CHECK(rc == MSX_ERR_INVALID_PARAMETER, "invalid model: rc %d, want MSX_ERR_INVALID_PARAMETER", (int)rc);
    CHECK(out == NULL, "invalid model must not create a handle");
    CHECK(memchr(err, 0, sizeof err) != NULL, "error message must be NUL-terminated");
    CHECK(strstr(err, "model") != NULL, "error message must name 'model': \"%s\"", err);
    printf("error message: %s\n", err);

    /* Truncation: never writes past err_len, always terminates. */
    memset(err, 'x', sizeof err);
    rc = msx_bsdf_new(&p, &out, err, 8);
    CHECK(rc == MSX_ERR_INVALID_PARAMETER, "truncated: rc %d", (int)rc);
    CHECK(err[7] == 0 && strlen(err) == 7 && err[8] == 'x', "error message must be truncated to err_len");

    /* No error buffer at all is fine. */
    rc = msx_bsdf_new(&p, &out, NULL, 0);
    CHECK(rc == MSX_ERR_INVALID_PARAMETER, "null err buffer: rc %d", (int)rc);

    p = make_params(MSX_MODEL_SINGLE);
    rc = msx_bsdf_new(NULL, &out, err, sizeof err);
    CHECK(rc == MSX_ERR_NULL_POINTER, "null params: rc %d", (int)rc);
    rc = msx_bsdf_new(&p, NULL, err, sizeof err);
    CHECK(rc == MSX_ERR_NULL_POINTER, "null out: rc %d", (int)rc);

    p.channels = 5;
    rc = msx_bsdf_new(&p, &out, err, sizeof err);
    CHECK(rc == MSX_ERR_INVALID_PARAMETER && strstr(err, "channels") != NULL, "channels = 5: rc %d \"%s\"", (int)rc,
          err);
    CHECK(out == NULL, "invalid channels must not create a handle");

    /* Null handle / material: zeros, no crash. */
    {
        MsxVec3 w = {0.0f, 0.0f, 1.0f};
        MsxSpectrum s = msx_eval(NULL, NULL, w, w, 0);
        MsxSample smp = msx_sample(NULL, NULL, w, 0.5f, 0.5f, 0.5f);
        CHECK(s.v[0] == 0.0f && msx_pdf(NULL, NULL, w, w) == 0.0f && smp.valid == 0, "null handle must give zeros");
    }
    msx_bsdf_free(NULL);
}

/* Batched calls with broadcast material arrays equal per-call results. */
static void test_batch(uint32_t model, const MsxMaterial *mat, const char *name) {
    enum { N = 300 };
    static float wix[N], wiy[N], wiz[N], wox[N], woy[N], woz[N], s1[N], s2x[N], s2y[N];
    static float val[3][N], pdf[N], wo_out[3][N], val4[N];
    MsxParams p = make_params(model);
    MsxBsdf *bsdf = NULL;
    MsxBatchIn in;
    MsxBatchOut out;
    char err[256];
    const uint64_t key = 0xfffffffffffffff0ull; /* key + i wraps around */
    int32_t rc;
    int i, c;

    rc = msx_bsdf_new(&p, &bsdf, err, sizeof err);
    CHECK(rc == MSX_OK && bsdf != NULL, "%s: msx_bsdf_new failed: %s", name, err);
    if (rc != MSX_OK) return;

    for (i = 0; i < N; i++) {
        MsxVec3 wi = to_f(dir(0.01 + 1.5 * i / N, 0.1 * i));
        MsxVec3 wo = to_f(dir(1.5 * ((i * 37) % N) / N, 2.3 + 0.07 * i));
        wix[i] = wi.x; wiy[i] = wi.y; wiz[i] = wi.z;
        wox[i] = wo.x; woy[i] = wo.y; woz[i] = wo.z;
        s1[i] = (float)((i * 0.618034) - floor(i * 0.618034));
        s2x[i] = (float)((i * 0.754878) - floor(i * 0.754878));
        s2y[i] = (float)((i * 0.569840) - floor(i * 0.569840));
        val4[i] = -1.0f;
    }

    memset(&in, 0, sizeof in);
    in.n = N;
    in.wi[0].ptr = wix; in.wi[0].len = N;
    in.wi[1].ptr = wiy; in.wi[1].len = N;
    in.wi[2].ptr = wiz; in.wi[2].len = N;
    in.wo[0].ptr = wox; in.wo[0].len = N;
    in.wo[1].ptr = woy; in.wo[1].len = N;
    in.wo[2].ptr = woz; in.wo[2].len = N;
    in.sample1.ptr = s1; in.sample1.len = N;
    in.sample2[0].ptr = s2x; in.sample2[0].len = N;
    in.sample2[1].ptr = s2y; in.sample2[1].len = N;
    /* Broadcast (len 1) material values. */
    in.alpha_u.ptr = &mat->alpha_u; in.alpha_u.len = 1;
    in.alpha_v.ptr = &mat->alpha_v; in.alpha_v.len = 1;
    for (c = 0; c < 4; c++) {
        in.eta[c].ptr = &mat->eta[c]; in.eta[c].len = 1;
        in.k[c].ptr = &mat->k[c]; in.k[c].len = 1;
        in.specular_reflectance[c].ptr = &mat->specular_reflectance[c]; in.specular_reflectance[c].len = 1;
    }
    in.key = key;

    memset(&out, 0, sizeof out);
    for (c = 0; c < 3; c++) out.value[c] = val[c];
    out.value[3] = val4;
    out.pdf = pdf;

    /* eval */
    rc = msx_eval_batch(bsdf, &in, &out, err, sizeof err);
    CHECK(rc == MSX_OK, "%s: msx_eval_batch rc %d: %s", name, (int)rc, err);
    for (i = 0; i < N; i++) {
        MsxVec3 wi = {wix[i], wiy[i], wiz[i]}, wo = {wox[i], woy[i], woz[i]};
        MsxSpectrum s = msx_eval(bsdf, mat, wi, wo, key + (uint64_t)i);
        for (c = 0; c < 3; c++)
            CHECK(same_bits(val[c][i], s.v[c]), "%s: eval_batch lane %d ch%d %.9g != msx_eval %.9g", name, i, c,
                  val[c][i], s.v[c]);
        CHECK(val4[i] == 0.0f, "%s: eval_batch channel 4 must be written as 0", name);
    }

    /* eval_pdf */
    rc = msx_eval_pdf_batch(bsdf, &in, &out, err, sizeof err);
    CHECK(rc == MSX_OK, "%s: msx_eval_pdf_batch rc %d: %s", name, (int)rc, err);
    for (i = 0; i < N; i++) {
        MsxVec3 wi = {wix[i], wiy[i], wiz[i]}, wo = {wox[i], woy[i], woz[i]};
        MsxEvalPdf e = msx_eval_pdf(bsdf, mat, wi, wo, key + (uint64_t)i);
        for (c = 0; c < 3; c++)
            CHECK(same_bits(val[c][i], e.value.v[c]), "%s: eval_pdf_batch lane %d ch%d differs", name, i, c);
        CHECK(same_bits(pdf[i], e.pdf), "%s: eval_pdf_batch lane %d pdf differs", name, i);
    }

    /* sample */
    for (c = 0; c < 3; c++) out.wo[c] = wo_out[c];
    rc = msx_sample_batch(bsdf, &in, &out, err, sizeof err);
    CHECK(rc == MSX_OK, "%s: msx_sample_batch rc %d: %s", name, (int)rc, err);
    for (i = 0; i < N; i++) {
        MsxVec3 wi = {wix[i], wiy[i], wiz[i]};
        MsxSample s = msx_sample(bsdf, mat, wi, s1[i], s2x[i], s2y[i]);
        CHECK(same_bits(wo_out[0][i], s.wo.x) && same_bits(wo_out[1][i], s.wo.y) && same_bits(wo_out[2][i], s.wo.z),
              "%s: sample_batch lane %d wo differs", name, i);
        CHECK(same_bits(pdf[i], s.pdf), "%s: sample_batch lane %d pdf differs", name, i);
        for (c = 0; c < 3; c++)
            CHECK(same_bits(val[c][i], s.weight.v[c]), "%s: sample_batch lane %d weight ch%d differs", name, i, c);
    }

    /* A length that is neither 1 nor n is an error naming the array. */
    in.wo[1].len = N - 1;
    rc = msx_eval_batch(bsdf, &in, &out, err, sizeof err);
    CHECK(rc == MSX_ERR_INVALID_PARAMETER && strstr(err, "wo.y") != NULL, "%s: length mismatch: rc %d \"%s\"", name,
          (int)rc, err);

    msx_bsdf_free(bsdf);
}

int main(void) {
    static const float none_eta[3] = {0.0f, 0.0f, 0.0f}, none_k[3] = {1.0f, 1.0f, 1.0f};
    static const float cu_eta[3] = {0.200438f, 0.924033f, 1.10221f}, cu_k[3] = {3.91295f, 2.45285f, 2.14219f};
    MsxParams p = make_params(MSX_MODEL_SINGLE);
    MsxBsdf *bsdf = NULL;
    MsxMaterial none = make_material(0.5, none_eta, none_k);
    MsxMaterial cu = make_material(0.5, cu_eta, cu_k);
    char err[256] = {0};
    int32_t rc;
    const char *version = msx_version();

    CHECK(version != NULL && version[0] != 0, "msx_version must be a non-empty string");
    printf("msx version %s\n", version ? version : "(null)");

    rc = msx_bsdf_new(&p, &bsdf, err, sizeof err);
    CHECK(rc == MSX_OK && bsdf != NULL, "msx_bsdf_new(single, ggx) failed: %d %s", (int)rc, err);
    if (rc != MSX_OK) {
        printf("FAIL\n");
        return 1;
    }

    test_single_closed_form(bsdf, &none, 1, "none");
    test_single_closed_form(bsdf, &cu, 0, "Cu");
    test_single_sample(bsdf, &none, 1, "none");
    test_single_sample(bsdf, &cu, 0, "Cu");
    msx_bsdf_free(bsdf);

    test_errors();
    test_batch(MSX_MODEL_SINGLE, &cu, "single/Cu");
    test_batch(MSX_MODEL_CORRELATED, &cu, "correlated/Cu");
    test_batch(MSX_MODEL_UNCORRELATED, &none, "uncorrelated/none");

    if (failures != 0) {
        printf("%d check(s) failed\n", failures);
        return 1;
    }
    printf("ok\n");
    return 0;
}
