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

/* As nvtmm_start, with the host application as the haptic device: the
 * configured device backend is replaced by the poses the host pushes with
 * nvtmm_push_pose; the force comes back through nvtmm_force. */
NvtmmService *nvtmm_start_host(const char *config_path, const char *config_toml, double seconds);

/* Pushes the host's device pose (a service from nvtmm_start_host), each tick
 * of the host's device loop: position (m, device frame, 3 doubles), gimbal
 * (rad, 3 doubles in HD_CURRENT_GIMBAL_ANGLES order, the stylus roll last;
 * NULL: zeros), buttons (bit 0 instrument switch, bit 1 contrast, bit 2
 * fluoroscopy). A pose older than the watchdog's device_timeout_ms ramps
 * the force to zero. Never blocks. Returns 0; -1 on a NULL argument or a
 * service without a host device; -2 for a non-finite number or a gimbal
 * angle beyond +-2 pi; -3 when the pose ring was full (the pose is dropped). */
int nvtmm_push_pose(const NvtmmService *service, const double position[3], const double gimbal[3], uint32_t buttons);

/* The newest force the service commanded on the host's device (N, device
 * frame) into out[3]; zero before the first and once stopped. Returns 0, or
 * -1 on a NULL argument or a service without a host device. */
int nvtmm_force(const NvtmmService *service, double out[3]);

/* Copies the latest frame's surface triangles (3 indices into the vertices of
 * nvtmm_frame_positions, counter-clockwise seen from outside the tissue)
 * into tri, which has room for max_triangles. Returns the number copied;
 * with tri NULL and max_triangles 0, the number there are; 0 before the
 * first frame; -1 on a NULL service. */
int64_t nvtmm_frame_triangles(const NvtmmService *service, uint32_t *tri, size_t max_triangles);

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
 * of points copied (with xyz NULL and max_points 0: the number there are),
 * or -1 on a NULL service or an index past the count. */
int64_t nvtmm_instrument_polyline(const NvtmmService *service, size_t index, uint8_t *kind, float *xyz,
                                  size_t max_points);

#ifdef __cplusplus
}
#endif

#endif /* NVTMM_H */
