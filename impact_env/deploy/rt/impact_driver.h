/*
 * The DAQ boundary: a driver is a few C functions over its own context, so that a loop does not
 * care whether it talks to a comedi device, a vendor's C API or a file of recorded readings
 * (replay_driver.c).  Two loops call it: the exported C runtime (main.c) and the target's
 * compiled real-time loop (impact-env rig serve --driver LIB.so, impact_env/rig/cdriver.py),
 * which calls read/apply through these pointers every tick with no Python in between.
 *
 * Units and signs are those of impact_policy.h: readings in SI (accelerometer m/s^2 down
 * positive, force N compression positive, potentiometer m down positive, body-1 sensor m or
 * NaN); the command is dimensionless, 1 = the scene's command scale in newtons upwards.
 *
 * The lifecycle (the target's order):
 *   impact_driver_open(&drv, config)   once, when the target starts: devices open, output 0
 *   per episode:  arm(seed) -> release() -> [read(tick), apply(tick, command)] ... -> idle()
 *   close()                            once, at exit: output 0, devices closed, ctx freed
 * read and apply run inside the tick (10 kHz): they must not block, allocate or take locks
 * another thread may hold; arm, release, idle and close run outside it and may block.
 *
 * Building a driver for the target (impact_real must be double there):
 *   gcc -std=c99 -O2 -shared -fPIC -DIMPACT_DRIVER_STANDALONE -I$d -o mydaq.so mydaq.c -lm
 * and impact-env rig serve --driver ./mydaq.so --driver-config "WHATEVER YOUR OPEN PARSES".
 */
#ifndef IMPACT_DRIVER_H
#define IMPACT_DRIVER_H

#include <stdint.h>

#ifdef IMPACT_DRIVER_STANDALONE
/* a driver library built without an exported policy (the target's --driver LIB.so) */
typedef double impact_real;
#define IMPACT_N_READINGS 4
#else
#include "impact_policy.h"
#endif

#define IMPACT_DRIVER_ABI 2

typedef struct impact_driver {
    void *ctx;
    /* the readings of tick `tick` (sampled at the tick's start); 0 ok, 1 no more data, <0 fault */
    int (*read)(void *ctx, int64_t tick, impact_real readings[IMPACT_N_READINGS]);
    /* hold `command` on the output from now until the next call; 0 ok, <0 fault */
    int (*apply)(void *ctx, int64_t tick, impact_real command);
    /* the output at 0 (end, fault, signal) */
    void (*idle)(void *ctx);
    /* a drop ready: body 1 on the electromagnet, body 2 at rest, output 0 (seed: may be logged); 0 ok */
    int (*arm)(void *ctx, uint64_t seed);
    /* drop body 1: tick 0 of the episode; 0 ok */
    int (*release)(void *ctx);
    /* output 0, devices closed, ctx freed (idempotent through the caller: called once) */
    void (*close)(void *ctx);
    uint32_t abi;       /* IMPACT_DRIVER_ABI: the target refuses another */
    uint32_t real_size; /* sizeof(impact_real): the target needs 8 (double) */
} impact_driver;

/* What a driver library exports for the target: fill *drv (every pointer) from `config` (the
 * string given to --driver-config; its syntax is the driver's); 0 ok, else an error code. */
int impact_driver_open(impact_driver *drv, const char *config);

/* replay_driver.c: readings from a file of float64 [n][4] (little-endian), commands to a file of
 * float64 [n] (NaN for ticks that were skipped). */
int replay_driver_open(impact_driver *drv, const char *readings_path, const char *commands_path,
                       int64_t *n_ticks);
void replay_driver_close(impact_driver *drv);

#endif
