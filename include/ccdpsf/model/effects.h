// The catalogue of physical effects beyond the paper's model, and their forward application.
//
// Each effect is an optional model component with physical parameters, a documented
// "realistic" default strength and a prior range for a fit. The simulator injects them
// ("effects" in the simulation config) so they can be hidden in test data; `ccdpsf diagnose`
// fits them as model components. The names are part of the interface (docs/formats.md):
//
//   defocus          the spot projector's defocus (the model's own component, docs/conventions.md,
//                    forward model). In the catalogue so that a baseline can leave it out, as in
//                    the paper's first model; never injected (the simulator's defocus is set
//                    in "model").
//   brighter_fatter  CCD widths grow linearly with the peak signal (paper section 4.3).
//   serial_cti       charge left behind in serial transfers: a one-sided trail along +x.
//   parallel_cti     the same in parallel transfers: a trail along +y.
//   ipc              coupling of each pixel to its four edge neighbours (a 3x3 kernel).
//   jitter           extra blur per exposure: an axis-aligned Gaussian and/or a linear motion.
//   background       a pedestal left after bias subtraction.
//   nonlinearity     a quadratic response near full well.
//   halo             a broad second component holding a fraction of the light (the
//                    red-light diffusion tail).
//   defocus_offset   the defocus kernel centred away from the Airy centre.
//   boundary_shift   brighter-fatter as a CCD makes it: pixel boundaries moved by the charge
//                    already collected (model/boundary_shift.h).
//
// Two kinds of effect, applied in this order (the order the simulator uses):
//
//   1. Kernel effects change the spot that the renderer draws (renderer.h):
//        brighter_fatter  ccd_sigma_{x,y} -> ccd_sigma_{x,y} + slope_{x,y} * I, where I is
//                         the expected peak-pixel electrons of the exposure rendered with every
//                         kernel effect except brighter_fatter (BrighterFatterSignal). The
//                         model's CCD widths are therefore the widths at zero signal.
//        jitter (Gaussian) sigma^2 -> sigma^2 + jitter_sigma^2 on each axis. A Gaussian blur
//                         convolved with the axis-aligned Gaussian CCD kernel is that kernel
//                         with the variances added, so in integrated sampling this is exact.
//                         In pixel_centre sampling (the 2015 discretisation) it is the same
//                         variance addition, which there is a definition, not a convolution.
//        jitter (motion)  the average of renders at centres spread along a segment of length
//                         L [px] at angle theta [deg, from +x towards +y], centred on the spot
//                         (so the mean position does not move); Gauss-Legendre nodes, their
//                         number chosen from an error bound (MotionBlurNodeCount).
//        boundary_shift   after the spot is drawn with the effects above: the charge of
//                         each pixel moves its neighbours' boundaries, and each boundary moves
//                         1/2 shift x (the line integral of the spot's continuous image along
//                         it) from one pixel to the other (model/boundary_shift.h, first
//                         order, the shifts growing during the exposure). Integrated sampling
//                         with the whole pixel collecting only: it needs the continuous image
//                         along the pixel boundaries. Computed in a window around the spot
//                         (BoundaryShiftWindow).
//        defocus_offset   the defocus kernel centred at (x + dx, y + dy) instead of the Airy
//                         centre (x, y). In integrated sampling a convolution with a shifted
//                         kernel is exactly a shift of the whole image, so this is rendered as
//                         a spot centred at (x + dx, y + dy): on its own it is
//                         indistinguishable from a change of position. In pixel_centre
//                         sampling the 2015 renderer centres its sampled F kernel at
//                         (x + dx, y + dy) while the Airy stays at (x, y)
//                         (SpotRenderer::RenderWithDefocusOffset): not a pure shift there.
//   2. Image effects act on an image of expected electrons, pixel by pixel or between pixels,
//      in this order:
//        halo          image = (1 - f) image + f * flux * H, H the unit-integral isotropic
//                      Gaussian of sigma s centred on the spot, integrated exactly over each
//                      pixel (erf, closed form).
//        nonlinearity  out = in (1 - beta in) per pixel. Beyond the turning point
//                      in = 1 / (2 beta) the response is held at its maximum 1 / (4 beta) (the
//                      well is full) rather than folding back.
//        ipc           3x3 kernel: 1 - 4 alpha at the centre, alpha on the four edge
//                      neighbours (charge conserving). Zero padding: nothing enters from outside
//                      the image, and the alpha an edge pixel gives away outwards is lost.
//        serial_cti    readout is towards x = 0, so charge left behind trails towards larger
//                      x. Each pixel keeps (1 - f) of its charge; f is spread over the pixels
//                      d = 1, 2, ... after it with weights (1 - r) r^(d - 1), r = exp(-1 / L),
//                      i.e. proportional to exp(-d / L) and summing to exactly 1 (evaluated by
//                      a recursion, so the trail is never truncated). Charge trailing past the
//                      edge of the image is lost.
//        parallel_cti  the same along y (readout towards y = 0).
//        background    + pedestal_e in every pixel.
//      Operating on the expected electrons (before the Poisson step) keeps the mean exact: the
//      charge effects are applied to the mean, and the simulator draws the shot noise of the
//      result. (Real CTI and IPC move the shot-noise-bearing charge, which correlates the noise
//      of neighbouring pixels at the level of f or alpha; that is neglected.) The background is
//      a bias residual: the simulator adds it after the Poisson step, without shot noise.
//
// Units: positions and widths in pixels [px] on the grid of spot_model.h (pixel (i, j)
// centred at (x0 + i, y0 + j)); charges in electrons [e-]. Everything is double precision: a
// fit takes numeric derivatives with respect to effect parameters.
#ifndef CCDPSF_MODEL_EFFECTS_H_
#define CCDPSF_MODEL_EFFECTS_H_

#include <array>
#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/model/boundary_shift.h"
#include "ccdpsf/model/renderer.h"
#include "ccdpsf/model/spot_model.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::model {

enum class EffectKind {
  kDefocus,
  kBrighterFatter,
  kSerialCti,
  kParallelCti,
  kIpc,
  kJitter,
  kBackground,
  kNonlinearity,
  kHalo,
  kDefocusOffset,
  kBoundaryShift,
};
constexpr int kNumEffectKinds = static_cast<int>(EffectKind::kBoundaryShift) + 1;

// The catalogue names ("defocus", "brighter_fatter", "serial_cti", "parallel_cti", "ipc",
// "jitter", "background", "nonlinearity", "halo", "defocus_offset", "boundary_shift").
// ParseEffectKind returns false on anything else and leaves the output untouched.
std::string ToString(EffectKind kind);
bool ParseEffectKind(const std::string& text, EffectKind* kind);
// Every kind, in the order above.
const std::vector<EffectKind>& AllEffectKinds();

// ---------------------------------------------------------------------------------------
// Parameters. The member defaults are the catalogue's "realistic" strengths; the reasoning
// behind each is in effects.cc next to the catalogue.

struct DefocusEffectParams {
  double sigma_px = 0.41;  // Gaussian sigma (or pillbox radius) of the defocus [px]
};

struct BrighterFatterParams {
  // Growth of the CCD sigma per electron in the peak pixel [px / e-]. Paper, 800 nm:
  // FWHM grows 1.14e-5 um per e-; / 12 um per px / 2.3548 = 4.0e-7 px per e-.
  double slope_x_px_per_e = 4.0e-7;
  double slope_y_px_per_e = 4.0e-7;
};

// Realistic strength (effects.cc has the reasoning): f = 1e-3, the order of n c for a spot
// ~1000 transfers from the output of an unirradiated CCD273 (c ~ 1e-6 per transfer for a
// bright charge packet); an irradiated device at the Euclid end-of-life fluence reaches ~1e-2.
struct CtiParams {
  double trail_fraction = 1.0e-3;  // fraction f of each pixel's charge found in its trail
  double trail_length_px = 1.5;    // e-folding length L of the trail [px]
};

struct IpcParams {
  double alpha = 0.01;  // fraction of a pixel's charge seen by each of its 4 edge neighbours
};

// One exposure's jitter. In the simulation config each value may be one number for every
// exposure or a list with one per exposure.
struct JitterParams {
  double sigma_x_px = 0.1;        // Gaussian blur sigma along x [px]
  double sigma_y_px = 0.1;        // ... along y [px]
  double motion_length_px = 0.0;  // length of a linear motion during the exposure [px]
  double motion_angle_deg = 0.0;  // its direction [deg], from +x towards +y
};

struct BackgroundParams {
  double pedestal_e = 20.0;  // added to every pixel [e-] (may be negative)
};

// Realistic strength: beta = 3e-8 / e-, a response 0.5 % low at 160 ke- (0.6 % at the ~200 ke-
// full well): the few-tenths-of-a-percent to one percent of a CCD output chain near full well.
struct NonlinearityParams {
  double beta_per_e = 3.0e-8;  // out = in (1 - beta in) [1 / e-]: 0.48 % low at 160 ke-
};

struct HaloParams {
  double fraction = 0.03;  // fraction f of the light in the halo
  double sigma_px = 2.5;   // halo Gaussian sigma [px]
};

struct DefocusOffsetParams {
  double dx_px = 0.1;  // defocus-kernel centre minus Airy centre [px]
  double dy_px = 0.0;
};

// The effects acting on one exposure; an absent effect is not part of the model. (defocus is
// not here: it is the model's own component, SpotParams[kDefocus].)
struct ExposureEffects {
  std::optional<BrighterFatterParams> brighter_fatter;
  std::optional<JitterParams> jitter;
  std::optional<DefocusOffsetParams> defocus_offset;
  std::optional<HaloParams> halo;
  std::optional<NonlinearityParams> nonlinearity;
  std::optional<IpcParams> ipc;
  std::optional<CtiParams> serial_cti;
  std::optional<CtiParams> parallel_cti;
  std::optional<BackgroundParams> background;
  std::optional<BoundaryShiftParams> boundary_shift;

  bool empty() const { return !HasKernelEffects() && !HasImageEffects(); }
  // Whether a kernel effect (an image effect) of the catalogue is present.
  bool HasKernelEffects() const;
  bool HasImageEffects() const;
  // Whether `kind` is present (kDefocus: always false).
  bool Has(EffectKind kind) const;
  // The kinds present, in catalogue order.
  std::vector<EffectKind> Kinds() const;
};

// ---------------------------------------------------------------------------------------
// The catalogue: names, units, defaults, priors, physical domains, starting points and how
// ExposureEffects holds each effect, for the simulator, the fit, the diagnose tool, reports
// and the parsers. An effect is added in one place: its entry in the catalogue (effects.cc),
// with its parameter struct and ExposureEffects member above and its physics (the kernel
// effects below, the image effects in image_effects.cc).

struct EffectParameterInfo {
  std::string name;         // JSON key, with its unit in the name (e.g. "trail_length_px")
  std::string unit;         // e.g. "px", "e-", "px/e-", "1/e-", "deg", "" (dimensionless)
  double default_value;     // the realistic strength
  double prior_lower;       // flat prior range for a fit
  double prior_upper;
  // Physical domain: values outside it are rejected. Open ends are exclusive.
  double domain_lower;
  double domain_upper;
  bool lower_open;
  bool upper_open;
  std::string description;  // one line
  // Where a fit that searches for the effect begins: a small strength inside the prior.
  // (A fit component, fit/fit_model.h, starts at "no effect" where its prior holds it.)
  double start;
  // Whether the parameter's "no effect" value lies on the prior's boundary (a strength
  // >= 0): such parameters are the boundary terms of diagnose's chi-bar-square test. False
  // for a value of either sign (a pedestal, an offset) and for a shape parameter that is a
  // nuisance when the strength is 0 (a trail's length, a halo's width).
  bool null_on_boundary;
};

struct EffectInfo {
  EffectKind kind;
  std::string name;
  std::string description;  // one line
  bool injectable;          // false for defocus
  bool kernel_effect;       // true: changes the rendered spot; false: acts on the image
  std::vector<EffectParameterInfo> parameters;
  // One to three starting points of a search (one value per parameter, in parameter order)
  // spanning the plausible range, so that a multimodal shape parameter (a trail's length, a
  // halo's width) is not missed.
  std::vector<std::vector<double>> search_starts;
  // Why the effect cannot be a component of a fit, shared by every exposure (one line);
  // empty when it can.
  std::string not_fittable;
  // How ExposureEffects holds the effect: whether it is present, its parameters in parameter
  // order (present only), and setting them, creating the effect, without domain checks.
  bool (*present)(const ExposureEffects& effects);
  std::vector<double> (*get)(const ExposureEffects& effects);
  void (*set)(const double* values, ExposureEffects* effects);
};

// Every effect, in AllEffectKinds() order. Parameter order is the order of EffectParameters.
const std::vector<EffectInfo>& EffectCatalogue();
const EffectInfo& DescribeEffect(EffectKind kind);
// A plain-text table of the catalogue: one block per effect, one line per parameter with its
// unit, default, prior range and description.
std::string FormatEffectCatalogue();
// The catalogue as JSON: [{"name":, "description":, "injectable":, "kind": "kernel"|"image",
// "parameters": [{"name":, "unit":, "default":, "prior": [lo, hi], "domain": "[lo, hi)",
// "description":}]}].
nlohmann::json EffectCatalogueJson();

// Whether `value` is finite and inside the parameter's physical domain.
bool InsideEffectDomain(const EffectParameterInfo& parameter, double value);
// Checks `value` against the domain of parameter `index` of `kind`. On failure returns false
// with a one-line reason naming `path` (e.g. "effects.ipc.alpha").
bool CheckEffectParameter(EffectKind kind, int index, double value, const std::string& path,
                          std::string* error);

// The parameters of one present effect as a vector in catalogue order, and back: the form a
// fit or the diagnose tool works with. GetEffectParameters CHECKs that the effect is present
// (kDefocus reads nothing and returns an empty vector); SetEffectParameters creates the effect
// if absent, checks each value's domain and returns false with a one-line reason otherwise
// (leaving `effects` untouched). Neither accepts kDefocus with parameters: defocus lives in
// SpotParams.
std::vector<double> GetEffectParameters(const ExposureEffects& effects, EffectKind kind);
bool SetEffectParameters(EffectKind kind, const std::vector<double>& values,
                         ExposureEffects* effects, std::string* error);
// SetEffectParameters without the checks, for values known to lie in the domain (a fit's
// prior box lies inside it) on a fit's hot path: `values` holds the effect's parameters in
// EffectParameters order. kDefocus CHECK-fails.
void SetEffectParametersUnchecked(EffectKind kind, const double* values, ExposureEffects* effects);
// The effect with its default parameters (kDefocus: CHECK-fails).
void AddDefaultEffect(EffectKind kind, ExposureEffects* effects);

// ---------------------------------------------------------------------------------------
// Kernel effects.

// The spot parameters handed to the renderer for one exposure when there is no motion blur,
// or the parameters at the centre of the motion segment otherwise: brighter_fatter with the
// peak signal `peak_e` [e-] (ignored without brighter_fatter), the Gaussian jitter added in
// quadrature, and (integrated sampling) the defocus offset added to the centre. `params` are
// the model's own (zero-signal CCD widths). In pixel_centre sampling the centre is left
// alone: RenderSpotWithKernelEffects hands the offset to the renderer.
SpotParams AdjustSpotParams(const ModelOptions& options, const ExposureEffects& effects,
                            const SpotParams& params, double peak_e);

// Number of Gauss-Legendre nodes n for a motion blur of length `length_px` at angle
// `angle_deg` of a spot whose Gaussian smoothing has total sigmas (sx, sy) [px] (CCD kernel
// plus jitter, plus the Gaussian defocus when there is one), so that the error of the averaged
// pixel values is at most `tolerance` times the flux. The bound: every pixel value is
// f(t) = (1 / 4 pi^2) Int M^(w) box^(w) e^{i w.(c + t u)} dw with |M^| <= flux exp(-w'S w / 2),
// S = diag(sx^2, sy^2) (the Airy OTF, the pillbox transform and the pixel box are all <= 1
// in modulus), so |f^(2n)| <= flux (2n - 1)!! s_u^(2n) / (2 pi sx sy), s_u^2 = cos^2 / sx^2 +
// sin^2 / sy^2; with the Gauss-Legendre remainder L^(2n+1) (n!)^4 / ((2n + 1) ((2n)!)^3)
// f^(2n) the error of the average is at most
//   flux L^(2n) (n!)^4 (2n - 1)!! s_u^(2n) / ((2n + 1) ((2n)!)^3 2 pi sx sy).
// Returns 1 for length 0 (no blur) and at most 4096. In pixel_centre sampling the same count
// is used with the 2015 widths; there the bound is a heuristic (that model is not a
// convolution with a smooth Gaussian in the centre).
int MotionBlurNodeCount(double length_px, double angle_deg, double sx_px, double sy_px,
                        double tolerance);

struct MotionNode {
  double dx_px;   // offset of the render's centre from the segment's centre [px]
  double dy_px;
  double weight;  // Gauss-Legendre weight / 2: the weights sum to 1
};
// The nodes of a motion blur with n nodes (n >= 1; n = 1 is the unblurred centre, weight 1).
std::vector<MotionNode> MotionBlurNodes(const JitterParams& jitter, int n);

// What the kernel effects did to one exposure, for the simulator's truth record.
struct KernelEffectDetails {
  double peak_e = 0.0;                 // brighter_fatter signal I used (0 without it)
  double ccd_sigma_x_px = 0.0;         // CCD widths after brighter_fatter, before jitter
  double ccd_sigma_y_px = 0.0;
  double rendered_sigma_x_px = 0.0;    // widths handed to the renderer (jitter included)
  double rendered_sigma_y_px = 0.0;
  double centre_x_px = 0.0;            // centre handed to the renderer (integrated: defocus
  double centre_y_px = 0.0;            // offset included; the motion segment's centre)
  double defocus_centre_x_px = 0.0;    // where the defocus kernel is centred (the Airy
  double defocus_centre_y_px = 0.0;    // centre plus the defocus offset, both samplings)
  int motion_nodes = 1;                // renders averaged (1 without motion blur)
};

// The brighter-fatter signal I of one exposure: the largest pixel of the spot rendered on
// `grid` with every kernel effect of `effects` except brighter_fatter [e-].
double BrighterFatterSignal(const SpotRenderer& renderer, const ExposureEffects& effects,
                            const SpotParams& params, const PixelGrid& grid);

// Renders the spot with the kernel effects onto `grid` (layout of renderer.h, no Jacobian):
// brighter_fatter from `peak_e`, jitter, defocus offset. `motion_nodes` = 0 chooses the node
// count with MotionBlurNodeCount at the renderer's relative tolerance; a positive value forces
// it (for convergence studies). `details` may be null.
void RenderSpotWithKernelEffects(const SpotRenderer& renderer, const ExposureEffects& effects,
                                 const SpotParams& params, const PixelGrid& grid,
                                 double peak_e, double* model,
                                 KernelEffectDetails* details = nullptr, int motion_nodes = 0);

// The same, with the brighter-fatter signal taken from BrighterFatterSignal (one extra set of
// renders when brighter_fatter is present).
void RenderSpotWithEffects(const SpotRenderer& renderer, const ExposureEffects& effects,
                           const SpotParams& params, const PixelGrid& grid, double* model,
                           KernelEffectDetails* details = nullptr);

// ---------------------------------------------------------------------------------------
// Image effects, on an image of expected electrons laid out on `grid` (row-major,
// image[j * grid.nx + i] is pixel (i, j) centred at (grid.x0 + i, grid.y0 + j)).

// Where the halo is centred and how much light the spot holds: the total electrons of the
// continuous spot (integrated sampling: flux_e; pixel_centre: the sum of the stamp's pixels,
// as m is not a flux) and its centre (the Airy centre) in the grid's coordinates.
struct SpotReference {
  double flux_e = 0.0;
  double x_px = 0.0;
  double y_px = 0.0;
};

// The integral over [a, b] of a unit-integral Gaussian of sigma s centred on 0 (s > 0),
// accurate to a few ulp of the smaller tail (erfc on the tail side).
double GaussianIntervalIntegral(double a, double b, double sigma);

// An image carrying forward-mode derivatives (src/model/image_effects.cc): per pixel (the
// row-major order above) its value [e-], then its derivatives d value / d u_c with respect to
// num_derivatives parameters u of the caller's choosing (a fit: the parameters the exposure
// depends on). The image effects apply to the derivative channels by the chain rule, and add
// the derivatives with respect to their own parameters in the channels EffectChannels names.
struct DualImage {
  int nx = 0;
  int ny = 0;
  int num_derivatives = 0;
  std::vector<double> data;  // nx * ny * stride()
  int stride() const { return num_derivatives + 1; }
};

// Which derivative channel (1 .. num_derivatives) receives the derivative with respect to
// parameter p (EffectParameters order) of an effect; -1 (the default) when none does.
constexpr int kMaxEffectParameters = 5;  // boundary_shift's (MakeCatalogue checks every entry)
class EffectChannels {
 public:
  EffectChannels();
  int Get(EffectKind kind, int parameter) const;
  void Set(EffectKind kind, int parameter, int channel);

 private:
  std::array<std::array<int, kMaxEffectParameters>, kNumEffectKinds> channel_;
};

// The derivatives of SpotReference's members in each derivative channel (index c - 1 holds
// channel c's); for the halo, which moves light in proportion to the flux, about the centre.
struct SpotReferenceDerivatives {
  std::vector<double> flux_e, x_px, y_px;
};

// Each effect on a DualImage; `spot_d` may be null (the reference does not depend on the
// parameters).
void AddHalo(const HaloParams& halo, const PixelGrid& grid, const SpotReference& spot,
             const SpotReferenceDerivatives* spot_d, const EffectChannels& channels,
             DualImage* image);
void ApplyNonlinearity(const NonlinearityParams& nonlinearity, const EffectChannels& channels,
                       DualImage* image);
void ApplyIpc(const IpcParams& ipc, const EffectChannels& channels, DualImage* image);
void ApplySerialCti(const CtiParams& cti, const EffectChannels& channels, DualImage* image);
void ApplyParallelCti(const CtiParams& cti, const EffectChannels& channels, DualImage* image);
void AddBackground(const BackgroundParams& background, const EffectChannels& channels,
                   DualImage* image);
// The spot's light where the boundary shifts move it, each with the image's derivative
// channels, drawn on the image's grid grown by one pixel below on the boundaries' axes
// (SpotRenderer::RenderBoundaryDensity and RenderCornerDensity):
struct BoundaryDensities {
  DualImage x;       // (nx + 1) x ny: line integrals along x = x0 - 1/2 + b of each row [e-/px]
  DualImage y;       // nx x (ny + 1): along y = y0 - 1/2 + b of each column [e-/px]
  DualImage corner;  // (nx + 1) x (ny + 1): the image at (x0 - 1/2 + b, y0 - 1/2 + c) [e-/px^2]
};
// The boundary shifts' redistribution of a drawn spot (model/boundary_shift.h; implemented in
// boundary_shift.cc): `image` holds the spot's pixels Q. Only the charge, the boundaries and
// the corners of `window` take part. The derivatives by a_10, a_01, a_11, a_far and
// anisotropy go to the channels EffectChannels names for kBoundaryShift.
void ApplyBoundaryShift(const BoundaryShiftParams& params, const BoundaryDensities& densities,
                        const PixelWindow& window, const EffectChannels& channels,
                        DualImage* image);
// halo -> nonlinearity -> ipc -> serial_cti -> parallel_cti: the charge effects, before
// the Poisson step.
void ApplyChargeEffects(const ExposureEffects& effects, const PixelGrid& grid,
                        const SpotReference& spot, const SpotReferenceDerivatives* spot_d,
                        const EffectChannels& channels, DualImage* image);
// ApplyChargeEffects, then the background: the expected electrons of the output.
void ApplyImageEffects(const ExposureEffects& effects, const PixelGrid& grid,
                       const SpotReference& spot, const SpotReferenceDerivatives* spot_d,
                       const EffectChannels& channels, DualImage* image);

// The same on a plain image of values.
void AddHalo(const HaloParams& halo, const PixelGrid& grid, const SpotReference& spot,
             double* image);
void ApplyNonlinearity(const NonlinearityParams& nonlinearity, int size, double* image);
void ApplyIpc(const IpcParams& ipc, int nx, int ny, double* image);
void ApplySerialCti(const CtiParams& cti, int nx, int ny, double* image);
void ApplyParallelCti(const CtiParams& cti, int nx, int ny, double* image);
void AddBackground(const BackgroundParams& background, int size, double* image);
void ApplyChargeEffects(const ExposureEffects& effects, const PixelGrid& grid,
                        const SpotReference& spot, double* image);
void ApplyImageEffects(const ExposureEffects& effects, const PixelGrid& grid,
                       const SpotReference& spot, double* image);

// ---------------------------------------------------------------------------------------
// Effects of a set of exposures, as the simulation config holds them.

struct EffectsConfig {
  // The effects of every exposure. Its jitter (if any) is the jitter of every exposure unless
  // jitter_per_exposure is non-empty.
  ExposureEffects common;
  // Jitter given as lists in the config: one entry per exposure (else empty).
  std::vector<JitterParams> jitter_per_exposure;

  bool empty() const { return common.empty() && jitter_per_exposure.empty(); }
  // The effects of exposure k (CHECK-fails if a jitter list is shorter than k + 1).
  ExposureEffects ForExposure(int k) const;
};

// Parses the "effects" object of a simulation config. `num_exposures` is the length any
// per-exposure list must have; `sampling` is for checks that depend on it (boundary_shift
// needs integrated sampling; the other effects render in both). boundary_shift and
// brighter_fatter describe one effect and are not injected together. Unknown
// effect names and keys, wrong types and values outside the physical domain are one-line
// errors naming the key (e.g. "'effects.ipc.alpha' must be in [0, 0.25) (got 0.3)"); "defocus"
// is rejected with a pointer to "model.defocus". Missing parameters take the catalogue
// defaults, with one exception: when a jitter motion key is given, a missing sigma_x_px or
// sigma_y_px is 0 (the Gaussian part only where asked for).
bool ParseEffectsConfig(const nlohmann::json& effects, int num_exposures, Sampling sampling,
                        EffectsConfig* out, std::string* error);

// The effects as JSON in the config's own form (parameters resolved, defaults included):
// {"<name>": {"<parameter>": value}}, jitter values as lists when given per exposure.
// {} when empty.
nlohmann::json EffectsConfigToJson(const EffectsConfig& config);

}  // namespace ccdpsf::model

#endif  // CCDPSF_MODEL_EFFECTS_H_
