// msx_posfree as a native Mitsuba 3 BSDF for the scalar variants: every BSDF
// call is one call into the Rust core (include/msx.h), with no Python and no
// GIL, so Mitsuba's render threads run in parallel.
//
// This plugin is an internal back end: msx.register() (mitsuba_plugin/msx/
// msx/plugin/native.py) registers "msx_posfree" as a Python factory that parses
// and validates the scene parameters exactly like the Python back end, then
// instantiates this class ("msx_posfree_native") with the parsed values:
//   strings  surface, distribution, model, estimator, seed (decimal u64),
//            mis_density ("default" where it does not apply)
//   int      max_bounces (0 = library default)
//   float    auto_tolerance (0 = library default), ior (dielectric)
//   bool     isotropic, sample_visible (false: MSX_SAMPLE_ALL_NORMALS; the
//            walks ignore it, the Python front end logs the line that says so)
//   textures alpha_u, alpha_v and, per surface, specular_reflectance
//            (conductor, dielectric), eta and k (conductor),
//            specular_transmittance (dielectric), reflectance (diffuse)
// It is compiled against the installed Mitsuba's own headers on first use
// (see msx/plugin/native.py), because the struct layouts must match the wheel.

#include <mitsuba/core/plugin.h>
#include <mitsuba/core/properties.h>
#include <mitsuba/render/bsdf.h>
#include <mitsuba/render/texture.h>

#include <stdexcept>
#include <string>

#include "msx.h"

NAMESPACE_BEGIN(mitsuba)

namespace {

// The surface, parsed once in the constructor (the per-call code compares it, never strings); its values
// are the core's codes (msx.h), so that it goes to msx_bsdf_new as it is.
enum class Surface : uint32_t {
    Conductor = MSX_SURFACE_CONDUCTOR,
    Dielectric = MSX_SURFACE_DIELECTRIC,
    Diffuse = MSX_SURFACE_DIFFUSE,
};

// The code of a parameter's value (MSX_CHOICE_*), from the core's table of names (msx_choice; the table is
// src/config.rs): a model added there is accepted here without a change to this file.
uint32_t parse(uint32_t parameter, const std::string &value) {
    std::string allowed;
    MsxChoice c;
    for (uint32_t i = 0; i < msx_choice_count(parameter) && msx_choice(parameter, i, &c) == MSX_OK; ++i) {
        if (value == c.name)
            return c.code;
        allowed += (allowed.empty() ? "" : ", ") + std::string(c.name);
    }
    // The Python front end validates the values first; the same one line as its (msx/plugin/parameters.py, _choice).
    const char *name = msx_choice_parameter(parameter);
    throw std::runtime_error("msx_posfree: unknown value '" + value + "' for parameter '" +
                             (name ? name : "?") + "'; allowed values: " + allowed);
}

// The name of a code, for to_string.
std::string name_of(uint32_t parameter, uint32_t code) {
    MsxChoice c;
    for (uint32_t i = 0; i < msx_choice_count(parameter) && msx_choice(parameter, i, &c) == MSX_OK; ++i)
        if (c.code == code)
            return c.name;
    return "?";
}

} // namespace

template <typename Float, typename Spectrum>
class MsxNativeBSDF final : public BSDF<Float, Spectrum> {
public:
    MI_IMPORT_BASE(BSDF, m_flags, m_components)
    MI_IMPORT_TYPES(Texture)
    static_assert(!dr::is_jit_v<Float>, "msx_posfree_native supports Mitsuba's scalar variants only");
    static constexpr size_t Channels = dr::size_v<UnpolarizedSpectrum>;
    static_assert(Channels >= 1 && Channels <= MSX_MAX_CHANNELS, "unsupported spectrum size");

    explicit MsxNativeBSDF(const Properties &props) : Base(props) {
        m_surface = (Surface) parse(MSX_CHOICE_SURFACE, props.get<std::string>("surface"));
        m_distribution = parse(MSX_CHOICE_DISTRIBUTION, props.get<std::string>("distribution"));
        m_model = parse(MSX_CHOICE_MODEL, props.get<std::string>("model"));
        m_estimator = parse(MSX_CHOICE_ESTIMATOR, props.get<std::string>("estimator"));
        // "default" (the Python front end's value where the parameter does not apply) is the ABI's 0.
        const std::string mis = props.get<std::string>("mis_density");
        m_mis_density = mis == "default" ? MSX_MIS_DENSITY_DEFAULT : parse(MSX_CHOICE_MIS_DENSITY, mis);
        MsxParams p{};
        p.surface = (uint32_t) m_surface;
        p.distribution = m_distribution;
        p.model = m_model;
        p.estimator = m_estimator;
        p.max_bounces = (uint32_t) props.get<int64_t>("max_bounces");
        p.channels = (uint32_t) Channels;
        p.seed = std::stoull(props.get<std::string>("seed"));
        p.auto_tolerance = props.get<double>("auto_tolerance");
        p.mis_density = m_mis_density;
        m_sample_visible = props.get<bool>("sample_visible");
        p.sample_all_normals = m_sample_visible ? MSX_SAMPLE_VISIBLE_NORMALS : MSX_SAMPLE_ALL_NORMALS;

        char err[512] = { 0 };
        MsxBsdf *handle = nullptr;
        if (msx_bsdf_new(&p, &handle, err, sizeof(err)) != MSX_OK)
            Throw("msx_posfree: %s", err);
        m_handle = handle;

        m_isotropic = props.get<bool>("isotropic");
        m_alpha_u = props.get_texture<Texture>("alpha_u");
        m_alpha_v = m_isotropic ? m_alpha_u : props.get_texture<Texture>("alpha_v");
        if (props.has_property("specular_reflectance")) // conductors and dielectrics only
            m_specular_reflectance = props.get_texture<Texture>("specular_reflectance");
        if (m_surface == Surface::Conductor) {
            m_eta = props.get_unbounded_texture<Texture>("eta");
            m_k = props.get_unbounded_texture<Texture>("k");
            m_lobe = +BSDFFlags::GlossyReflection;
        } else if (m_surface == Surface::Dielectric) {
            m_ior = (float) props.get<double>("ior");
            m_specular_transmittance = props.get_texture<Texture>("specular_transmittance");
            m_lobe = BSDFFlags::GlossyReflection | BSDFFlags::GlossyTransmission;
        } else {
            m_reflectance = props.get_texture<Texture>("reflectance");
            m_lobe = +BSDFFlags::DiffuseReflection;
        }
        parameters_changed({});
    }

    ~MsxNativeBSDF() override { msx_bsdf_free(m_handle); }

    void traverse(TraversalCallback *cb) override {
        auto flags = ParamFlags::Differentiable | ParamFlags::Discontinuous;
        if (m_isotropic) {
            cb->put("alpha", m_alpha_u, flags);
        } else {
            cb->put("alpha_u", m_alpha_u, flags);
            cb->put("alpha_v", m_alpha_v, flags);
        }
        if (m_eta) {
            cb->put("eta", m_eta, flags);
            cb->put("k", m_k, flags);
        }
        if (m_specular_reflectance)
            cb->put("specular_reflectance", m_specular_reflectance, +ParamFlags::Differentiable);
        if (m_specular_transmittance)
            cb->put("specular_transmittance", m_specular_transmittance, +ParamFlags::Differentiable);
        if (m_reflectance)
            cb->put("reflectance", m_reflectance, +ParamFlags::Differentiable);
    }

    void parameters_changed(const std::vector<std::string> & /*keys*/ = {}) override {
        if (m_isotropic)
            m_alpha_v = m_alpha_u;
        // A material without spatial or spectral variation is evaluated once.
        m_constant = true;
        for (const Texture *t : textures()) {
            if (t->is_spatially_varying())
                m_constant = false;
            if constexpr (is_spectral_v<Spectrum>)
                if (t->class_name() != std::string_view("UniformSpectrum") && t != m_alpha_u.get() &&
                    t != m_alpha_v.get())
                    m_constant = false;
        }
        if (m_constant)
            m_material = evaluate(dr::zeros<SurfaceInteraction3f>(), true);

        m_flags = m_lobe | BSDFFlags::FrontSide;
        if (m_surface == Surface::Dielectric)
            m_flags = m_flags | BSDFFlags::BackSide | BSDFFlags::NonSymmetric;
        // Anisotropic when the two roughnesses can differ (as the Python back end decides).
        bool alpha_const = !m_alpha_u->is_spatially_varying() && !m_alpha_v->is_spatially_varying();
        auto si0 = dr::zeros<SurfaceInteraction3f>();
        if (!m_isotropic && (!alpha_const || m_alpha_u->eval_1(si0, true) != m_alpha_v->eval_1(si0, true)))
            m_flags = m_flags | BSDFFlags::Anisotropic;
        bool varying = false;
        for (const Texture *t : textures())
            varying |= t->is_spatially_varying();
        if (varying)
            m_flags = m_flags | BSDFFlags::SpatiallyVarying;
        m_components.clear();
        if (m_surface == Surface::Dielectric) {
            uint32_t extra = m_flags & ~m_lobe;
            m_components.push_back((uint32_t) BSDFFlags::GlossyReflection | extra);
            m_components.push_back((uint32_t) BSDFFlags::GlossyTransmission | extra);
        } else {
            m_components.push_back(m_flags);
        }
    }

    std::pair<BSDFSample3f, Spectrum> sample(const BSDFContext &ctx, const SurfaceInteraction3f &si,
                                             Float sample1, const Point2f &sample2,
                                             Mask active) const override {
        BSDFSample3f bs = dr::zeros<BSDFSample3f>();
        bs.eta = 1.f;
        bs.sampled_component = 0;
        bs.sampled_type = +first_lobe();
        bool r_on = reflection_enabled(ctx), t_on = transmission_enabled(ctx);
        if (!active || !(r_on || t_on))
            return { bs, 0.f };
        MsxMaterial mat = material(ctx, si);
        MsxSample r = msx_sample(m_handle, &mat, vec(si.wi), sample1, sample2.x(), sample2.y());
        if (!r.valid)
            return { bs, 0.f };
        // Only a dielectric transmits; a conductor's ω_i may lie below a tilted shading normal.
        bool transmit = m_surface == Surface::Dielectric && r.wo.z * si.wi.z() < 0.f;
        if (!(transmit ? t_on : r_on))
            return { bs, 0.f };
        bs.wo = Vector3f(r.wo.x, r.wo.y, r.wo.z);
        bs.pdf = r.pdf;
        if (transmit) {
            bs.eta = si.wi.z() > 0.f ? m_ior : 1.f / m_ior;
            bs.sampled_type = +BSDFFlags::GlossyTransmission;
            bs.sampled_component = 1;
        }
        return { bs, spectrum(r.weight) };
    }

    Spectrum eval(const BSDFContext &ctx, const SurfaceInteraction3f &si, const Vector3f &wo,
                  Mask active) const override {
        if (!active || !lobe_enabled(ctx, si, wo))
            return 0.f;
        MsxMaterial mat = material(ctx, si);
        return spectrum(msx_eval(m_handle, &mat, vec(si.wi), vec(wo), key(si)));
    }

    Float pdf(const BSDFContext &ctx, const SurfaceInteraction3f &si, const Vector3f &wo,
              Mask active) const override {
        if (!active || !lobe_enabled(ctx, si, wo))
            return 0.f;
        MsxMaterial mat = material(ctx, si);
        return msx_pdf(m_handle, &mat, vec(si.wi), vec(wo));
    }

    std::pair<Spectrum, Float> eval_pdf(const BSDFContext &ctx, const SurfaceInteraction3f &si,
                                        const Vector3f &wo, Mask active) const override {
        if (!active || !lobe_enabled(ctx, si, wo))
            return { 0.f, 0.f };
        MsxMaterial mat = material(ctx, si);
        MsxEvalPdf r = msx_eval_pdf(m_handle, &mat, vec(si.wi), vec(wo), key(si));
        return { spectrum(r.value), r.pdf };
    }

    std::string to_string() const override {
        std::ostringstream oss;
        oss << "MsxPosfree[native," << std::endl
            << "  surface = \"" << name_of(MSX_CHOICE_SURFACE, (uint32_t) m_surface) << "\"," << std::endl
            << "  distribution = \"" << name_of(MSX_CHOICE_DISTRIBUTION, m_distribution) << "\"," << std::endl
            << "  model = \"" << name_of(MSX_CHOICE_MODEL, m_model) << "\"," << std::endl
            << "  estimator = \"" << name_of(MSX_CHOICE_ESTIMATOR, m_estimator) << "\"," << std::endl
            << "  sample_visible = " << (m_sample_visible ? "true" : "false") << "," << std::endl
            << "  mis_density = \"" << (m_mis_density == MSX_MIS_DENSITY_DEFAULT ? std::string("default") : name_of(MSX_CHOICE_MIS_DENSITY, m_mis_density)) << "\"," << std::endl
            << "  alpha_u = " << string::indent(m_alpha_u) << "," << std::endl
            << "  alpha_v = " << string::indent(m_alpha_v) << std::endl
            << "]";
        return oss.str();
    }

    MI_DECLARE_CLASS(MsxNativeBSDF)

private:
    std::vector<const Texture *> textures() const {
        std::vector<const Texture *> out{ m_alpha_u.get(), m_alpha_v.get() };
        for (const ref<Texture> *t : { &m_specular_reflectance, &m_eta, &m_k, &m_specular_transmittance, &m_reflectance })
            if (*t)
                out.push_back(t->get());
        return out;
    }

    BSDFFlags first_lobe() const {
        return m_surface == Surface::Diffuse ? BSDFFlags::DiffuseReflection : BSDFFlags::GlossyReflection;
    }

    bool reflection_enabled(const BSDFContext &ctx) const { return ctx.is_enabled(first_lobe(), 0); }

    bool transmission_enabled(const BSDFContext &ctx) const {
        return m_surface == Surface::Dielectric && ctx.is_enabled(BSDFFlags::GlossyTransmission, 1);
    }

    bool lobe_enabled(const BSDFContext &ctx, const SurfaceInteraction3f &si, const Vector3f &wo) const {
        if (m_surface != Surface::Dielectric)
            return reflection_enabled(ctx);
        return si.wi.z() * wo.z() > 0.f ? reflection_enabled(ctx) : transmission_enabled(ctx);
    }

    static MsxVec3 vec(const Vector3f &v) { return MsxVec3{ v.x(), v.y(), v.z() }; }

    // The key of msx_eval*: where the call happens (the core hashes it with the
    // directions and the seed), so an estimate never depends on thread scheduling.
    static uint64_t key(const SurfaceInteraction3f &si) {
        return msx_call_key(si.p.x(), si.p.y(), si.p.z(), si.uv.x(), si.uv.y());
    }

    static Spectrum spectrum(const MsxSpectrum &s) {
        UnpolarizedSpectrum out;
        for (size_t c = 0; c < Channels; ++c)
            out[c] = s.v[c];
        return out;
    }

    template <typename Value> static void put(float *dst, const Value &v) {
        for (size_t c = 0; c < Channels; ++c)
            dst[c] = v[c];
    }

    /// Material values at the hit (textures evaluated there), radiance mode.
    MsxMaterial evaluate(const SurfaceInteraction3f &si, bool /*unused*/) const {
        MsxMaterial m{};
        m.alpha_u = m_alpha_u->eval_1(si, true);
        m.alpha_v = m_isotropic ? m.alpha_u : m_alpha_v->eval_1(si, true);
        for (size_t c = 0; c < 4; ++c) {
            m.k[c] = 1.f; // a perfect mirror in the fields this surface does not use
            m.specular_transmittance[c] = m.specular_reflectance[c] = m.reflectance[c] = 1.f;
        }
        if (m_specular_reflectance)
            put(m.specular_reflectance, m_specular_reflectance->eval(si, true));
        if (m_eta) {
            put(m.eta, m_eta->eval(si, true));
            put(m.k, m_k->eval(si, true));
        }
        if (m_specular_transmittance)
            put(m.specular_transmittance, m_specular_transmittance->eval(si, true));
        if (m_reflectance)
            put(m.reflectance, m_reflectance->eval(si, true));
        m.ior = m_ior;
        m.mode = MSX_MODE_RADIANCE;
        return m;
    }

    MsxMaterial material(const BSDFContext &ctx, const SurfaceInteraction3f &si) const {
        MsxMaterial m = m_constant ? m_material : evaluate(si, true);
        if (ctx.mode == TransportMode::Importance)
            m.mode = MSX_MODE_IMPORTANCE;
        return m;
    }

    MsxBsdf *m_handle = nullptr;
    Surface m_surface = Surface::Conductor;
    // MSX_DISTRIBUTION_*, MSX_MODEL_*, MSX_ESTIMATOR_* codes (the per-call code does not branch on them).
    uint32_t m_distribution = MSX_DISTRIBUTION_BECKMANN;
    uint32_t m_model = MSX_MODEL_CORRELATED;
    uint32_t m_estimator = MSX_ESTIMATOR_PT;
    uint32_t m_mis_density = MSX_MIS_DENSITY_DEFAULT;  // MSX_MIS_DENSITY_* (0: the default)
    bool m_sample_visible = true;  // Mitsuba's sample_visible (MsxParams::sample_all_normals)
    uint32_t m_lobe = +BSDFFlags::GlossyReflection;
    bool m_isotropic = true, m_constant = false;
    float m_ior = (float) MSX_DEFAULT_IOR;
    ref<Texture> m_alpha_u, m_alpha_v, m_eta, m_k, m_specular_reflectance, m_specular_transmittance, m_reflectance;
    MsxMaterial m_material{};
};

NAMESPACE_END(mitsuba)

namespace {

template <typename Float, typename Spectrum>
mitsuba::ref<mitsuba::Object> instantiate(void *, const mitsuba::Properties &props) {
    return new mitsuba::MsxNativeBSDF<Float, Spectrum>(props);
}

void release(void *) {}

} // namespace

/// Registers the plugin `name` for the scalar variants this build has.
/// Returns the number of variants registered.
extern "C" __attribute__((visibility("default"))) int msx_native_register(const char *name) {
    using namespace mitsuba;
    auto *pm = PluginManager::instance();
    pm->register_plugin(name, "scalar_rgb", ObjectType::BSDF, instantiate<float, Color<float, 3>>, release, nullptr);
    pm->register_plugin(name, "scalar_spectral", ObjectType::BSDF, instantiate<float, mitsuba::Spectrum<float, 4>>,
                        release, nullptr);
    return 2;
}

/// Sizes of the Mitsuba structs this build was compiled with (bytes), for a
/// consistency check against the running Mitsuba: BSDFSample3f, SurfaceInteraction3f.
extern "C" __attribute__((visibility("default"))) void msx_native_layout(uint64_t *out) {
    using namespace mitsuba;
    out[0] = sizeof(BSDFSample3<float, Color<float, 3>>);
    out[1] = sizeof(SurfaceInteraction<float, Color<float, 3>>);
    out[2] = sizeof(BSDFContext);
}
