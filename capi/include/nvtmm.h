/* nvtmm: the haptic service of the nonlinear viscoelastic tensor-mass vessel
 * simulator, as a C library (libnvtmm_capi.so / .a, built by
 * `cargo build --release -p nvtmm-capi`).
 *
 * The service runs on its own threads inside your process: the 1 kHz
 * haptic loop on the reduced model, the device I/O, the background full
 * solve and the state publisher. Poll nvtmm_snapshot() at your frame rate;
 * stop it with nvtmm_stop(). Units: SI (m, N, s). Thread-safe: snapshots may
 * be taken from any thread; start and stop one service from one thread.
 *
 * Errors: functions return NULL or -1; nvtmm_last_error() then says why
 * (naming the configuration file and key where the error is in it).
 */
#ifndef NVTMM_H
#define NVTMM_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* An opaque running service. */
typedef struct NvtmmService NvtmmService;

/* Live figures of a running service. */
typedef struct NvtmmSnapshot {
    double elapsed_s;            /* wall time since start (s) */
    uint64_t ticks;              /* haptic loop ticks so far */
    uint64_t deadline_misses;    /* ticks that ended after the next deadline */
    uint32_t flags;              /* status bits of the last tick (docs/SERVICE.md) */
    uint32_t frame_vertices;     /* vertices of the latest state frame (0: none yet) */
    double force_n[3];           /* force commanded on the last tick (N) */
    double tool_m[3];            /* tool centre on the last tick (m, scene frame) */
    double max_force_n;          /* largest force so far (N) */
    uint64_t background_steps;   /* full steps of the background solve so far */
    double background_real_time_factor; /* simulated / wall time of the full solve */
    double frame_time_s;         /* loop time of the latest state frame (s) */
} NvtmmSnapshot;

/* Starts the service. config_path: a TOML configuration file, or NULL for
 * rt-config/nvtmm.toml. config_toml: configuration text to use instead of
 * reading config_path (relative paths in it resolve against the directory of
 * config_path), or NULL. seconds > 0: length of the simulated hand's script.
 * Returns NULL on error. */
NvtmmService *nvtmm_start(const char *config_path, const char *config_toml, double seconds);

/* Fills *out with the live figures. Returns 0, or -1 on a NULL argument. */
int nvtmm_snapshot(const NvtmmService *service, NvtmmSnapshot *out);

/* Copies the latest frame's vertex positions (x, y, z per vertex, m) into
 * xyz, which has room for max_vertices vertices. Returns the number copied
 * (0 before the first frame), or -1 on a NULL argument. */
int64_t nvtmm_frame_positions(const NvtmmService *service, float *xyz, size_t max_vertices);

/* Stops the service and frees it. Returns the end-of-run report as JSON
 * (docs/SERVICE.md lists its keys; free it with nvtmm_string_free), or NULL
 * on error. The service pointer is invalid afterwards either way. */
char *nvtmm_stop(NvtmmService *service);

/* Frees a string returned by nvtmm_stop. */
void nvtmm_string_free(char *s);

/* The last error on the calling thread ("" if none). */
const char *nvtmm_last_error(void);

/* Instruments (docs/INSTRUMENTS.md): the number of instruments in the latest
 * frame (the probe, the guidewire, ...; 0 before the first frame), or -1 on
 * a NULL argument. */
int64_t nvtmm_instrument_count(const NvtmmService *service);

/* Copies instrument `index`'s polyline from the latest frame (x, y, z per
 * point, m, hub to tip; the probe's one point is its sphere's centre) into
 * xyz, which has room for max_points points, and its kind code into *kind
 * (1 probe, 2 guidewire, 3 catheter; kind may be NULL). Returns the number
 * of points copied, or -1 on a NULL argument or an index past the count. */
int64_t nvtmm_instrument_polyline(const NvtmmService *service, size_t index, uint8_t *kind, float *xyz,
                                  size_t max_points);

#ifdef __cplusplus
}
#endif

#endif /* NVTMM_H */
