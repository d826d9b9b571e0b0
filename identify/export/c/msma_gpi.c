/* msma_gpi.c: the GPI model (plus effects) and its inverse as streaming step functions; see msma_gpi.h.
 * Written by `python -m identify export` (msma-gpi). C99, libm only: no allocation, no global state.
 *
 * The forward step is model.Model.evaluate (model/gpi.py, model/gpi_kernels.py, model/effects/) taken
 * one sample at a time, with the same operations in the same order; the inverse is model.inverse's
 * kernel (model/inverse_search.py, its step model/inverse_step.py; per sample: a bracketed root
 * find in the present current, committed with the model's state).
 * Compile with floating-point contraction off (-ffp-contract=off) for the Python figures to
 * rounding; the code is plain C99 either way.
 */
#include "msma_gpi.h"

#include <math.h>
#include <string.h>

/* model.effects: the normalised heating's reference current, the logarithmic creep's modes */
#define REFERENCE_CURRENT 5.0
#define LOG_CREEP_MODES_PER_DECADE 2.0
#define LOG_CREEP_MODE_WEIGHT 0.5
#define LOG_CREEP_REACH 10.0
#define CREEP_STEP_HOLD 1e-12
#define MAX_ITERATIONS 200
#define EDGE_WIDTH 16.0 /* a side's edge is located to this many xtol */
#define DOUBLE_EPSILON 2.220446049250313e-16

/* Python's max(a, b) and min(a, b): the first unless the second is strictly beyond it. */
static double pmax(double a, double b) { return b > a ? b : a; }
static double pmin(double a, double b) { return b < a ? b : a; }
static double sign(double x) { return x > 0.0 ? 1.0 : (x < 0.0 ? -1.0 : 0.0); }

/* k0 tanh(k1 v + k2) + k3: eqs. (6), (7), (13) */
static double envelope(const double *k, double v) { return k[0] * tanh(k[1] * v + k[2]) + k[3]; }

/* One operator's memory at t_0 (model.gpi.initial_operator_memory). */
static double initial_memory(double level, double threshold, double rising, double falling, double excursion,
                             double excursion_env) {
    double lower = rising - threshold;
    double upper = falling + threshold;
    double memory = pmax(lower, pmin(upper, level));
    if (excursion > 0.0) {
        memory = pmin(pmax(memory, excursion_env - threshold), upper);
    } else if (excursion < 0.0) {
        memory = pmax(pmin(memory, excursion_env + threshold), lower);
    }
    return memory;
}

/* (decay, gain) of one exact step of tau du/dt = x - u with x linear over the step (tau > 0). */
static void lowpass_coefficients(double step, double tau, double *decay, double *gain) {
    double ratio = step / tau;
    double a = exp(-ratio);
    *decay = a;
    if (ratio > 1e-3) {
        *gain = (1.0 - a) / ratio;
    } else {
        *gain = 1.0 - ratio * (0.5 - ratio * (1.0 / 6.0 - ratio * (1.0 / 24.0 - ratio / 120.0)));
    }
}

/* model.effects._lowpass_step: tau <= 0 passes x_now. */
static double lowpass_step(double state, double x_prev, double x_now, double step, double tau) {
    double decay, gain;
    if (tau <= 0.0) return x_now;
    lowpass_coefficients(step, tau, &decay, &gain);
    return x_now - (x_now - x_prev) * gain + decay * (state - x_prev);
}

/* The output at the end of the last completed leg (model.effects._leg_end_level). */
static void leg_end_level(double y_prev, double y_before, double held, double last_direction, double *held_out,
                          double *direction_out) {
    double change = y_prev - y_before;
    double direction;
    if (change == 0.0) {
        *held_out = y_prev;
        *direction_out = last_direction;
        return;
    }
    direction = change > 0.0 ? 1.0 : -1.0;
    if (last_direction != 0.0 && direction != last_direction) held = y_before;
    *held_out = held;
    *direction_out = direction;
}

static int finite_all(const double *values, size_t n) {
    size_t j;
    for (j = 0; j < n; j++) {
        if (!isfinite(values[j])) return 0;
    }
    return 1;
}

/* The checks both directions share: finite values, the domains the effects take. */
static int check_params(const msma_params *p) {
    const double gpi[19] = {p->alpha, p->rho, p->tau, p->a0, p->a1, p->a2, p->a3, p->b0, p->b1, p->b2,
                            p->b3, p->c0, p->c1, p->c2, p->c3, p->d0, p->d1, p->d2, p->d3};
    if (!finite_all(gpi, 19)) return MSMA_BAD_PARAMETER;
    if (p->has_lag && !(isfinite(p->lag_tau) && p->lag_delay == 0.0)) return MSMA_BAD_PARAMETER;
    if (p->has_training) {
        const double tr[6] = {p->training_deficit, p->training_threshold, p->training_travel,
                              p->training_shape,   p->training_gain,      p->training_width};
        if (!finite_all(tr, 6) || !(p->training_travel > 0.0 && p->training_shape > 0.0)) return MSMA_BAD_PARAMETER;
        if (!(p->training_threshold >= 0.0)) return MSMA_BAD_PARAMETER;
    }
    if (p->has_initial_state) {
        const double is[4] = {p->initial_state_memory, p->initial_state_excursion, p->initial_state_held,
                              p->initial_state_held_slope};
        if (!finite_all(is, 4)) return MSMA_BAD_PARAMETER;
    }
    if (p->has_creep) {
        const double cp[6] = {p->creep_amplitude, p->creep_tau,       p->creep_decades,
                              p->creep_log_rate,  p->creep_log_onset, p->creep_log_hold};
        if (!finite_all(cp, 6) || !(p->creep_log_onset > 0.0)) return MSMA_BAD_PARAMETER;
        if (!finite_all(p->creep_mode_tau, MSMA_CREEP_MODES)) return MSMA_BAD_PARAMETER;
        if (!(p->creep_log_modes >= 1 && p->creep_log_modes <= MSMA_LOG_CREEP_MAX_MODES)) return MSMA_BAD_PARAMETER;
        if (!finite_all(p->creep_log_tau, (size_t)p->creep_log_modes)) return MSMA_BAD_PARAMETER;
    }
    if (p->has_thermal) {
        const double th[8] = {p->thermal_tau,      p->thermal_sensitivity,      p->thermal_expansion,
                              p->thermal_tau_core, p->thermal_sensitivity_core, p->thermal_expansion_core,
                              p->thermal_initial,  p->thermal_initial_core};
        if (!finite_all(th, 8)) return MSMA_BAD_PARAMETER;
    }
    if (p->has_sensor_drift) {
        const double sd[7] = {p->sensor_drift_linear,         p->sensor_drift_quadratic,
                              p->sensor_drift_settling,       p->sensor_drift_settling_tau,
                              p->sensor_drift_ambient_sine,   p->sensor_drift_ambient_cosine,
                              p->sensor_drift_ambient_period};
        if (!finite_all(sd, 7) || !(p->horizon >= 0.0 && isfinite(p->horizon))) return MSMA_BAD_PARAMETER;
    }
    return MSMA_OK;
}

/* The rising and falling envelopes of the reading, Omega's two branches. */
static void gpi_coefficients(const msma_params *p, double *rising, double *falling, double *omega_c, double *omega_d) {
    const double a[4] = {p->a0, p->a1, p->a2, p->a3};
    const double b[4] = {p->b0, p->b1, p->b2, p->b3};
    int q;
    for (q = 0; q < 4; q++) {
        rising[q] = p->rising_is_a ? a[q] : b[q];
        falling[q] = p->rising_is_a ? b[q] : a[q];
    }
    omega_c[0] = p->c0, omega_c[1] = p->c1, omega_c[2] = p->c2, omega_c[3] = p->c3;
    omega_d[0] = p->d0, omega_d[1] = p->d1, omega_d[2] = p->d2, omega_d[3] = p->d3;
}

/* Thresholds r_j = alpha j and weights p_j = rho exp(-tau r_j), eqs. (8)-(9). */
static void operators(const msma_params *p, double *threshold, double *weight) {
    int j;
    for (j = 0; j < MSMA_N_OPERATORS; j++) {
        threshold[j] = p->alpha * (j + 1);
        weight[j] = p->rho * exp(-p->tau * threshold[j]);
    }
}

/* The held memory h_j = h + s j/N of initial_state. */
static double held_memory(const msma_params *p, int j) {
    return p->initial_state_held + p->initial_state_held_slope * ((double)(j + 1) / MSMA_N_OPERATORS);
}

/* model.effects.creep_time_constants and log_creep_time_constants (the horizon as the duration). */
void msma_creep_constants(msma_params *p) {
    int m, count;
    double reach, ratio;
    for (m = 0; m < MSMA_CREEP_MODES; m++) {
        double position = m * (1.0 / (MSMA_CREEP_MODES - 1)) + -0.5;
        p->creep_mode_tau[m] = p->creep_tau * pow(10.0, p->creep_decades * position);
    }
    reach = LOG_CREEP_REACH * pmax(p->horizon, 1e-300);
    ratio = pmax(reach / p->creep_log_onset, 1.0 + 1e-12);
    count = (int)ceil(LOG_CREEP_MODES_PER_DECADE * log10(ratio));
    if (count < 1) count = 1;
    if (count > MSMA_LOG_CREEP_MAX_MODES) count = MSMA_LOG_CREEP_MAX_MODES;
    for (m = 0; m < MSMA_LOG_CREEP_MAX_MODES; m++) {
        p->creep_log_tau[m] = m < count ? p->creep_log_onset * pow(10.0, (m + 1) / LOG_CREEP_MODES_PER_DECADE) : 0.0;
    }
    p->creep_log_modes = count;
}

/* ---------------------------------------------------------------------------------------- */
/* forward model                                                                            */
/* ---------------------------------------------------------------------------------------- */
int msma_forward_init(msma_forward *m, const msma_params *p) {
    int status = check_params(p);
    if (status != MSMA_OK) return status;
    memset(m, 0, sizeof *m);
    m->p = *p;
    gpi_coefficients(p, m->rising, m->falling, m->omega_c, m->omega_d);
    operators(p, m->threshold, m->weight);
    if (p->has_creep) m->n_log = p->creep_log_modes;
    return MSMA_OK;
}

/* The weighted memory sum in four interleaved partial sums (model.gpi_kernels._weighted_sum's order). */
static double weighted_sum(const double *weight, const double *memory) {
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int j = 0;
    while (j + 4 <= MSMA_N_OPERATORS) {
        s0 += weight[j] * memory[j];
        s1 += weight[j + 1] * memory[j + 1];
        s2 += weight[j + 2] * memory[j + 2];
        s3 += weight[j + 3] * memory[j + 3];
        j += 4;
    }
    while (j < MSMA_N_OPERATORS) {
        s0 += weight[j] * memory[j];
        j += 1;
    }
    return (s0 + s1) + (s2 + s3);
}

/* The GPI's output at a sample that moves the drive to u (direction d), eq. (5) and (12). */
static double gpi_move(msma_forward *m, double u, int d, double width) {
    double s[4] = {0.0, 0.0, 0.0, 0.0};
    int j;
    if (d > 0) {
        double env = envelope(m->rising, u);
        for (j = 0; j < MSMA_N_OPERATORS; j++) {
            double z = pmax(m->memory[j], env - m->threshold[j] * width);
            m->memory[j] = z;
            s[j < MSMA_N_OPERATORS - MSMA_N_OPERATORS % 4 ? j % 4 : 0] += m->weight[j] * z;
        }
        return envelope(m->omega_c, u) + ((s[0] + s[1]) + (s[2] + s[3]));
    }
    {
        double env = envelope(m->falling, u);
        for (j = 0; j < MSMA_N_OPERATORS; j++) {
            double z = pmin(m->memory[j], env + m->threshold[j] * width);
            m->memory[j] = z;
            s[j < MSMA_N_OPERATORS - MSMA_N_OPERATORS % 4 ? j % 4 : 0] += m->weight[j] * z;
        }
        return envelope(m->omega_d, u) + ((s[0] + s[1]) + (s[2] + s[3]));
    }
}

/* The sensor drift at elapsed time e (model.effects.SensorDrift.drift). */
/* The displacement y with the thermal network's effect at the nodes' rises; node 2 only where its
 * gains are not both 0 (model.effects.thermal's _thermal_output). */
static double thermal_output(const msma_params *p, double y, double rise, double rise2) {
    if (p->thermal_sensitivity_core != 0.0 || p->thermal_expansion_core != 0.0) {
        return y * (1.0 - p->thermal_sensitivity * rise - p->thermal_sensitivity_core * rise2) +
               p->thermal_expansion * rise + p->thermal_expansion_core * rise2;
    }
    return y * (1.0 - p->thermal_sensitivity * rise) + p->thermal_expansion * rise;
}

static double sensor_drift(const msma_params *p, double e) {
    double s = p->horizon > 0.0 ? e / p->horizon : 0.0;
    double drift = p->sensor_drift_linear * s + p->sensor_drift_quadratic * (s * s);
    if (p->sensor_drift_settling != 0.0) {
        drift += p->sensor_drift_settling * -expm1(-e / p->sensor_drift_settling_tau);
    }
    if (p->sensor_drift_ambient_sine != 0.0 || p->sensor_drift_ambient_cosine != 0.0) {
        double phase = (2.0 * 3.141592653589793 / p->sensor_drift_ambient_period) * e;
        drift += p->sensor_drift_ambient_sine * sin(phase);
        drift += p->sensor_drift_ambient_cosine * (1.0 - cos(phase));
    }
    return drift;
}

/* Creep (model.effects._creep_kernel) of the strain y_now after y_prev; the modes advance. */
static double creep_step(msma_forward *m, double step, double y_prev, double y_now) {
    const msma_params *p = &m->p;
    double value = y_now;
    int q;
    if (fabs(step - m->creep_step) > CREEP_STEP_HOLD * step) {
        m->creep_step = step;
        for (q = 0; q < MSMA_CREEP_MODES; q++) {
            if (p->creep_mode_tau[q] > 0.0) lowpass_coefficients(step, p->creep_mode_tau[q], &m->creep_decay[q], &m->creep_gain[q]);
        }
        for (q = 0; q < m->n_log; q++) {
            lowpass_coefficients(step, p->creep_log_tau[q], &m->creep_decay[MSMA_CREEP_MODES + q],
                                 &m->creep_gain[MSMA_CREEP_MODES + q]);
        }
    }
    if (p->creep_amplitude != 0.0) {
        double total = 0.0;
        for (q = 0; q < MSMA_CREEP_MODES; q++) {
            if (p->creep_mode_tau[q] > 0.0) {
                m->modes[q] = y_now - (y_now - y_prev) * m->creep_gain[q] + m->creep_decay[q] * (m->modes[q] - y_prev);
            } else {
                m->modes[q] = y_now;
            }
            total += m->modes[q];
        }
        value -= p->creep_amplitude * (y_now - total / MSMA_CREEP_MODES);
    }
    if (p->creep_log_rate != 0.0 && m->n_log > 0) {
        double x_before = y_prev, x_now = y_now, grown = 0.0;
        if (p->creep_log_hold != 0.0) {
            double y_before = m->k >= 2 ? m->y_strain_before : m->y_strain_first;
            leg_end_level(y_prev, y_before, m->creep_held, m->creep_direction, &m->creep_held, &m->creep_direction);
            x_before = m->creep_x_prev;
            x_now = (1.0 - p->creep_log_hold) * y_now + p->creep_log_hold * m->creep_held;
            m->creep_x_prev = x_now;
        }
        for (q = 0; q < m->n_log; q++) {
            int j = MSMA_CREEP_MODES + q;
            m->logs[q] = x_now - (x_now - x_before) * m->creep_gain[j] + m->creep_decay[j] * (m->logs[q] - x_before);
            grown += m->logs[q] - m->y_strain_first;
        }
        value += p->creep_log_rate * LOG_CREEP_MODE_WEIGHT * grown;
    }
    return value;
}

double msma_forward_step(msma_forward *m, double t, double i) {
    const msma_params *p = &m->p;
    double u1 = i, u = i, width = 1.0, y_gpi, y_strain, y, heating, quotient;
    int j;
    if (m->k == 0) {
        double level = 0.0, excursion = 0.0, excursion_env = 0.0, rising, falling;
        if (p->has_initial_state) {
            level = p->initial_state_memory;
            excursion = p->initial_state_excursion;
        }
        rising = envelope(m->rising, u);
        falling = envelope(m->falling, u);
        if (excursion > 0.0) {
            excursion_env = envelope(m->rising, u + excursion);
        } else if (excursion < 0.0) {
            excursion_env = envelope(m->falling, u + excursion);
        }
        for (j = 0; j < MSMA_N_OPERATORS; j++) {
            m->memory[j] = initial_memory(level, m->threshold[j], rising, falling, excursion, excursion_env);
            if (p->has_initial_state) m->memory[j] += held_memory(p, j);
        }
        y_gpi = envelope(m->omega_c, u) + weighted_sum(m->weight, m->memory);
        m->t0 = t;
        m->u1_first = u1;
        m->travel = 0.0;
        m->travel_i = 0.0;
        m->y_gpi_first = y_gpi;
        y_strain = y_gpi;
        if (p->has_training && p->training_gain != 0.0) {
            y_strain = y_gpi + p->training_gain * 1.0 * (y_gpi - y_gpi);
        }
        m->y_strain_first = y_strain;
        m->y_strain_before = y_strain;
        for (j = 0; j < MSMA_CREEP_MODES; j++) m->modes[j] = y_strain;
        for (j = 0; j < MSMA_LOG_CREEP_MAX_MODES; j++) m->logs[j] = y_strain;
        m->creep_step = -1.0;
        m->creep_held = y_strain;
        m->creep_direction = 0.0;
        m->creep_x_prev = y_strain;
        y = y_strain;
        m->rise = p->has_thermal ? p->thermal_initial : 0.0; /* the nodes' rises at the run's start */
        m->rise2 = p->has_thermal ? p->thermal_initial_core : 0.0;
        if (p->has_thermal) y = thermal_output(p, y, m->rise, m->rise2);
    } else {
        double h = t - m->t_prev, dv;
        if (p->has_lag) u1 = lowpass_step(m->u1_prev, m->i_prev, i, h, p->lag_tau);
        u = u1;
        if (p->has_training) {
            double fade, excursion, kept;
            m->travel = m->travel + fabs(u1 - m->u1_prev);
            fade = exp(-pow(m->travel / p->training_travel, p->training_shape));
            excursion = u1 - m->u1_first;
            kept = sign(excursion) * pmax(fabs(excursion) - p->training_threshold * fade, 0.0);
            u = u1 - (excursion - kept * (1.0 - p->training_deficit * fade));
            if (p->training_width != 0.0) width = 1.0 + p->training_width * fade;
        }
        dv = u - m->u_prev;
        if (dv > 0.0) {
            y_gpi = gpi_move(m, u, 1, width);
        } else if (dv < 0.0) {
            y_gpi = gpi_move(m, u, -1, width);
        } else {
            y_gpi = m->y_gpi_prev; /* a still drive: memories and Omega's branch unchanged, the output repeats */
        }
        y_strain = y_gpi;
        m->travel_i = m->travel_i + fabs(i - m->i_prev);
        if (p->has_training && p->training_gain != 0.0) {
            double fade = exp(-pow(m->travel_i / p->training_travel, p->training_shape));
            y_strain = y_gpi + p->training_gain * fade * (y_gpi - m->y_gpi_first);
        }
        y = y_strain;
        if (p->has_creep) y = creep_step(m, h, m->y_strain_prev, y_strain);
        if (p->has_thermal) {
            double previous = m->rise;
            quotient = i / REFERENCE_CURRENT;
            heating = quotient * quotient;
            m->rise = lowpass_step(m->rise, m->heating_prev, heating, h, p->thermal_tau);
            if (p->thermal_sensitivity_core != 0.0 || p->thermal_expansion_core != 0.0) {
                m->rise2 = lowpass_step(m->rise2, previous, m->rise, h, p->thermal_tau_core);
            }
            y = thermal_output(p, y, m->rise, m->rise2);
        }
        m->y_strain_before = m->y_strain_prev;
    }
    if (p->has_sensor_drift) y = y + sensor_drift(p, t - m->t0);
    quotient = i / REFERENCE_CURRENT;
    m->heating_prev = quotient * quotient;
    m->t_prev = t;
    m->i_prev = i;
    m->u1_prev = u1;
    m->u_prev = u;
    m->y_gpi_prev = y_gpi;
    m->y_strain_prev = y_strain;
    m->k += 1;
    return y;
}

int msma_forward_run(const msma_params *p, size_t n, const double *t, const double *i, double *y) {
    msma_forward m;
    size_t k;
    int status = msma_forward_init(&m, p);
    if (status != MSMA_OK) return status;
    for (k = 0; k < n; k++) y[k] = msma_forward_step(&m, t[k], i[k]);
    return MSMA_OK;
}

/* ---------------------------------------------------------------------------------------- */
/* inverse (model/inverse.py: the search in inverse_search.py, the step in inverse_step.py)  */
/* ---------------------------------------------------------------------------------------- */
/* Scalar state st[] (as the Python kernel): 0 i_prev, 1 u1_prev (lag output), 2 training's i_0,
 * 3 travel, 4 u_prev (GPI drive), 5 previous sample on Omega's c branch, 6 GPI output prev,
 * 7 temperature rise (node 1), 8 initial memory level z0, 9 heating prev, 10 the current's
 * travel, 11 the GPI output at the first sample, 12 the strain prev, 13 temperature rise of
 * node 2, 14 initial excursion, 15 the strain two samples back, 16 its last direction of
 * change, 17 the strain held at the last leg's end, 18 the logarithmic creep's input prev. */

typedef struct {
    double y, y_gpi, u1, u, travel, y_strain, width, y_stage; /* y_stage: the thermal stage's input */
    int side;
} evaluation;

static double filter_step(double state, double x_prev, double x_now, double gain, double decay, int active) {
    if (!active) return x_now;
    return x_now - (x_now - x_prev) * gain + decay * (state - x_prev);
}

static void filter_coefficients(double step, double tau, double *gain, double *decay, int *active) {
    if (tau <= 0.0) {
        *gain = 1.0, *decay = 0.0, *active = 0;
        return;
    }
    lowpass_coefficients(step, tau, decay, gain);
    *active = 1;
}

static void initial_envelopes(const double *g, double u, double excursion, double *rising, double *falling,
                              double *excursion_env) {
    *excursion_env = 0.0;
    if (excursion > 0.0) {
        *excursion_env = envelope(g, u + excursion);
    } else if (excursion < 0.0) {
        *excursion_env = envelope(g + 4, u + excursion);
    }
    *rising = envelope(g, u);
    *falling = envelope(g + 4, u);
}

/* The input stage for current i (drive_step): the lag's output u1, the drive u the hysteresis sees,
 * the drive's travel and training's fading factor at it (1 without training). */
static inline void drive(const msma_inverse *c, double i, int first, double *u1, double *u, double *travel,
                         double *fade) {
    const double *st = c->st, *tr = c->tr;
    *u1 = first ? i : filter_step(st[1], st[0], i, c->lag_c[0], c->lag_c[1], c->lag_c[2] > 0.5);
    *travel = 0.0;
    *fade = 1.0;
    *u = *u1;
    if (c->p.has_training) {
        double excursion, kept;
        *travel = first ? 0.0 : st[3] + fabs(*u1 - st[1]);
        *fade = exp(-pow(*travel / tr[2], tr[3]));
        excursion = first ? 0.0 : *u1 - st[2];
        kept = sign(excursion) * pmax(fabs(excursion) - tr[1] * *fade, 0.0);
        *u = *u1 - (excursion - kept * (1.0 - tr[0] * *fade));
    }
}

/* Creep's modes advanced to the present sample are affine in the strain there (each is one
 * filter step of it from the committed state): their sums' slope and offset (a[0], a[1] the
 * saturating modes; a[2], a[3] the logarithmic ones, in their input) and the level held at the
 * last leg's end (a[4]), once per sample instead of at every model step of the search. */
static void creep_prepare(msma_inverse *c) {
    const double *st = c->st, *cp = c->cp;
    double *a = c->creep_affine, x_prev = st[12];
    int n_sat = (int)cp[1], n_log = (int)cp[3], q;
    a[0] = a[1] = a[2] = a[3] = 0.0;
    a[4] = 0.0;
    for (q = 0; q < n_sat; q++) {
        if (c->creep_active[q]) {
            a[0] += 1.0 - c->creep_gain[q];
            a[1] += c->creep_gain[q] * st[12] + c->creep_decay[q] * (c->modes[q] - st[12]);
        } else {
            a[0] += 1.0;
        }
    }
    if (cp[4] != 0.0) {
        double direction;
        leg_end_level(st[12], st[15], st[17], st[16], &a[4], &direction);
        x_prev = st[18];
    }
    for (q = n_sat; q < n_sat + n_log; q++) {
        if (c->creep_active[q]) {
            a[2] += 1.0 - c->creep_gain[q];
            a[3] += c->creep_gain[q] * x_prev + c->creep_decay[q] * (c->modes[q] - x_prev);
        } else {
            a[2] += 1.0;
        }
        a[3] -= st[11];
    }
}

/* The model's output at the present sample for current i, from the committed state (_evaluate).
 * side != 0 (a search on that side): a drive off that side returns at once with e.side set and
 * nothing else computed (the search's objective is -inf there whatever the output). */
static evaluation evaluate(const msma_inverse *c, double i, int first, int side) {
    const double *st = c->st, *g = c->g, *tr = c->tr, *cp = c->cp, *th = c->th;
    const msma_params *p = &c->p;
    evaluation e;
    double s, fade;
    int j;
    drive(c, i, first, &e.u1, &e.u, &e.travel, &fade);
    if (side != 0 && !first) {
        double dv = e.u - st[4];
        e.side = dv > 0.0 ? 1 : (dv < 0.0 ? -1 : (st[5] > 0.5 ? 1 : -1));
        if (e.side != side) return e;
    }
    e.width = 1.0;
    if (p->has_training && tr[5] != 0.0) e.width = 1.0 + tr[5] * fade;
    if (first) {
        double rising, falling, excursion_env;
        initial_envelopes(g, e.u, st[14], &rising, &falling, &excursion_env);
        s = 0.0;
        for (j = 0; j < MSMA_N_OPERATORS; j++) {
            s += c->weight[j] *
                 (initial_memory(st[8], c->threshold[j], rising, falling, st[14], excursion_env) + c->memory[j]);
        }
        e.y_gpi = envelope(g + 8, e.u) + s;
        e.side = 1;
    } else {
        double dv = e.u - st[4];
        if (dv > 0.0) {
            double env = envelope(g, e.u);
            s = 0.0;
            for (j = 0; j < MSMA_N_OPERATORS; j++) s += c->weight[j] * pmax(c->memory[j], env - c->threshold[j] * e.width);
            e.y_gpi = envelope(g + 8, e.u) + s;
            e.side = 1;
        } else if (dv < 0.0) {
            double env = envelope(g + 4, e.u);
            s = 0.0;
            for (j = 0; j < MSMA_N_OPERATORS; j++) s += c->weight[j] * pmin(c->memory[j], env + c->threshold[j] * e.width);
            e.y_gpi = envelope(g + 12, e.u) + s;
            e.side = -1;
        } else { /* a still drive: the memories and Omega's branch as at the sample before */
            e.side = st[5] > 0.5 ? 1 : -1;
            e.y_gpi = st[6];
        }
    }
    e.y_strain = e.y_gpi;
    if (p->has_training && tr[4] != 0.0 && !first) {
        double travel_i = st[10] + fabs(i - st[0]); /* the drive's travel itself without a lag */
        double fade_i = travel_i == e.travel ? fade : exp(-pow(travel_i / tr[2], tr[3]));
        e.y_strain = e.y_gpi + tr[4] * fade_i * (e.y_gpi - st[11]);
    }
    e.y = e.y_strain;
    if (p->has_creep && !first) { /* the modes' filter steps, summed ahead (creep_prepare) */
        const double *a = c->creep_affine;
        if (cp[0] != 0.0) e.y = e.y - cp[0] * (e.y_strain - (a[0] * e.y_strain + a[1]) / cp[1]);
        if (cp[2] != 0.0 && cp[3] > 0.0) {
            double x_now = cp[4] != 0.0 ? (1.0 - cp[4]) * e.y_strain + cp[4] * a[4] : e.y_strain;
            e.y = e.y + cp[2] * LOG_CREEP_MODE_WEIGHT * (a[2] * x_now + a[3]);
        }
    }
    e.y_stage = e.y;
    if (p->has_thermal) {
        double rise = th[7], rise2 = th[8]; /* the nodes' rises at the run's start */
        if (!first) {
            double quotient = i / th[3];
            double heating = quotient * quotient;
            rise = filter_step(st[7], st[9], heating, c->thermal_c[0], c->thermal_c[1], c->thermal_c[2] > 0.5);
            rise2 = filter_step(st[13], st[7], rise, c->thermal_c[3], c->thermal_c[4], c->thermal_c[5] > 0.5);
        }
        if (th[5] != 0.0 || th[6] != 0.0) {
            e.y = e.y * (1.0 - th[1] * rise - th[5] * rise2) + th[2] * rise + th[6] * rise2;
        } else {
            e.y = e.y * (1.0 - th[1] * rise) + th[2] * rise;
        }
    }
    return e;
}

/* Advance the state with the chosen current i; returns the output (_commit). */
static double commit(msma_inverse *c, double i, int first) {
    const msma_params *p = &c->p;
    const double *g = c->g, *cp = c->cp, *th = c->th;
    double *st = c->st;
    evaluation e = evaluate(c, i, first, 0);
    int j;
    if (first) {
        double rising, falling, excursion_env;
        initial_envelopes(g, e.u, st[14], &rising, &falling, &excursion_env);
        for (j = 0; j < MSMA_N_OPERATORS; j++) {
            c->memory[j] =
                initial_memory(st[8], c->threshold[j], rising, falling, st[14], excursion_env) + c->memory[j];
        }
        for (j = 0; j < MSMA_ALL_CREEP_MODES; j++) c->modes[j] = e.y_gpi;
        st[15] = e.y_strain;
        st[16] = 0.0;
        st[17] = e.y_strain;
        st[18] = e.y_strain;
        st[7] = c->th[7];
        st[13] = c->th[8];
        st[5] = 1.0;
        st[10] = 0.0;
        st[11] = e.y_gpi;
    } else {
        double dv = e.u - st[4];
        if (dv > 0.0) {
            double env = envelope(g, e.u);
            for (j = 0; j < MSMA_N_OPERATORS; j++) c->memory[j] = pmax(c->memory[j], env - c->threshold[j] * e.width);
        } else if (dv < 0.0) {
            double env = envelope(g + 4, e.u);
            for (j = 0; j < MSMA_N_OPERATORS; j++) c->memory[j] = pmin(c->memory[j], env + c->threshold[j] * e.width);
        }
        if (p->has_creep) {
            int n_sat = (int)cp[1], q;
            double x_prev = st[12], x_now = e.y_strain;
            for (q = 0; q < n_sat; q++) {
                c->modes[q] = filter_step(c->modes[q], st[12], e.y_strain, c->creep_gain[q], c->creep_decay[q],
                                          c->creep_active[q]);
            }
            if (cp[4] != 0.0) {
                double held, direction;
                leg_end_level(st[12], st[15], st[17], st[16], &held, &direction);
                x_prev = st[18];
                x_now = (1.0 - cp[4]) * e.y_strain + cp[4] * held;
                st[16] = direction;
                st[17] = held;
                st[18] = x_now;
            }
            for (q = n_sat; q < n_sat + (int)cp[3]; q++) {
                c->modes[q] = filter_step(c->modes[q], x_prev, x_now, c->creep_gain[q], c->creep_decay[q],
                                          c->creep_active[q]);
            }
            st[15] = st[12];
        }
        if (p->has_thermal) {
            double quotient = i / th[3];
            double heating = quotient * quotient;
            double previous = st[7];
            st[7] = filter_step(st[7], st[9], heating, c->thermal_c[0], c->thermal_c[1], c->thermal_c[2] > 0.5);
            st[13] = filter_step(st[13], previous, st[7], c->thermal_c[3], c->thermal_c[4], c->thermal_c[5] > 0.5);
        }
        st[5] = dv > 0.0 ? 1.0 : (dv < 0.0 ? 0.0 : st[5]); /* Omega's branch: the last motion's */
        st[10] = st[10] + fabs(i - st[0]);
    }
    if (first) st[2] = e.u1;
    st[0] = i;
    st[1] = e.u1;
    st[3] = e.travel;
    st[4] = e.u;
    st[6] = e.y_gpi;
    st[12] = e.y_strain;
    if (p->has_thermal) {
        double quotient = i / th[3];
        st[9] = quotient * quotient;
    }
    return e.y;
}

/* s (y(s x) - target) on side s, -inf off it (search coordinate x = s i) (_objective). */
static double objective(msma_inverse *c, double x, int s, double target, int first) {
    evaluation e = evaluate(c, s * x, first, s);
    c->evaluations += 1;
    if (!first && e.side != s) return -INFINITY;
    c->y_stage = e.y_stage;
    return s * (e.y - target);
}

static double magnitude(double f) { return f == -INFINITY ? INFINITY : fabs(f); }

/* The most the thermal stage can lower F from the current i0 on a side (its input y_stage there)
 * to any current beyond i0 (ahead > 0: up to hi, < 0: down
 * to lo): |E - S y_stage| times the most the rise can change, both nodes (the rise is affine in the
 * present heating (i / 5 A)^2, weight 1 - gain per node), a quarter's margin, plus htol (_thermal_fall). */
static double thermal_fall(const msma_inverse *c, double y_stage, double i0, double ahead, int first) {
    const double *th = c->th, *tc = c->thermal_c;
    double a, b, h_max, h_min, heating, rise, rise2;
    if (!c->p.has_thermal || first) return 0.0;
    a = ahead > 0 ? i0 : c->lo;
    b = ahead > 0 ? c->hi : i0;
    h_max = pmax(a * a, b * b);
    h_min = a < 0.0 && 0.0 < b ? 0.0 : pmin(a * a, b * b);
    heating = pmax(h_max - i0 * i0, i0 * i0 - h_min) / (th[3] * th[3]);
    rise = (tc[2] > 0.5 ? 1.0 - tc[0] : 1.0) * heating;
    rise2 = (tc[5] > 0.5 ? 1.0 - tc[3] : 1.0) * rise;
    return 1.25 * (fabs(th[2] - th[1] * y_stage) * rise + fabs(th[6] - th[5] * y_stage) * rise2) + c->htol;
}

/* s (u(s x) - u_prev): how far the drive moves toward side s, the input stage alone (_gap). */
static double gap(const msma_inverse *c, double x, int s, int first) {
    double u1, u, travel, fade;
    drive(c, s * x, first, &u1, &u, &travel, &fade);
    return s * (u - c->st[4]);
}

/* Whether a drive gap d lies on side s: a still drive keeps the last motion's (_on_side). */
static int on_side(const msma_inverse *c, double d, int s) {
    return d > 0.0 || (d == 0.0 && (c->st[5] > 0.5) == (s > 0));
}

/* The point on side s within EDGE_WIDTH xtol of its edge, between xa (off the side, gap da) and xb
 * (on it, gap db), on the drive alone: Illinois on the gap, each point at least EDGE_WIDTH xtol
 * inside the bracket, a bisection when the last two steps did not halve the bracket (_edge). */
static double edge(const msma_inverse *c, double xa, double da, double xb, double db, int s, int first) {
    const double limit = EDGE_WIDTH * c->xtol;
    double ga = da, gb = db, width_1 = INFINITY, width_2 = INFINITY;
    int last = 0, it;
    for (it = 0; it < MAX_ITERATIONS; it++) {
        double width = fabs(xb - xa), toward = xb > xa ? 1.0 : -1.0, x, d;
        if (width <= limit) break;
        if (gb > ga && width <= 0.5 * width_2 && width > 2.0 * limit) {
            x = xb - gb * (xb - xa) / (gb - ga);
            x = pmin(pmax(toward * (x - xa), limit), width - limit) * toward + xa;
        } else {
            x = 0.5 * (xa + xb);
        }
        width_2 = width_1, width_1 = width;
        d = gap(c, x, s, first);
        if (on_side(c, d, s)) {
            xb = x, gb = d;
            if (last == 1) ga *= 0.5;
            last = 1;
        } else {
            xa = x, ga = d;
            if (last == -1) gb *= 0.5;
            last = -1;
        }
    }
    return xb;
}

/* Brent's next step from xcur (*scur) and the step before it (*spre): the secant (xpre the bracket's
 * other end) or inverse quadratic step when the last steps shrank and it stays well inside the
 * bracket, else the bisection sbis (always while an end is off the side) (_brent_step). */
static void brent_step(double xpre, double fpre, double xcur, double fcur, double xblk, double fblk, double sbis,
                       double delta, int finite, double *spre, double *scur) {
    if (finite && fabs(*spre) > delta && fabs(fcur) < fabs(fpre)) {
        double stry;
        if (xpre == xblk) {
            stry = -fcur * (xcur - xpre) / (fcur - fpre);
        } else {
            double dpre = (fpre - fcur) / (xpre - xcur), dblk = (fblk - fcur) / (xblk - xcur);
            stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre));
        }
        if (2.0 * fabs(stry) < pmin(fabs(*spre), 3.0 * fabs(sbis) - delta)) {
            *spre = *scur, *scur = stry;
            return;
        }
    }
    *spre = sbis, *scur = sbis;
}

/* Where on side s the drive reaches the first operator it moves, in the search coordinate: the
 * end of the dead zone a reversal leaves, where the output starts to follow the drive (on the
 * rising side the operators move once the envelope passes min_j (m_j + r_j w), on the falling side
 * once it passes below max_j (m_j - r_j w); the envelope's tanh inverted there). The current: one
 * secant step on the drive alone from x0 and a unit slope (exact for an affine input stage). A
 * start for the probes, not a root: NAN when no operator is reached or the end lies behind x0
 * (_dead_zone_end). */
static double dead_zone_end(const msma_inverse *c, double x0, int s, int first) {
    const double *g = c->g + (s > 0 ? 0 : 4);
    double u1, u, travel, fade, width = 1.0, level = s * INFINITY, arg, distance, d0, xb, db, x;
    int j;
    if (first) return NAN;
    drive(c, s * x0, first, &u1, &u, &travel, &fade);
    if (c->p.has_training && c->tr[5] != 0.0) width = 1.0 + c->tr[5] * fade;
    for (j = 0; j < MSMA_N_OPERATORS; j++) {
        double v = c->memory[j] + s * c->threshold[j] * width;
        level = s > 0 ? pmin(level, v) : pmax(level, v);
    }
    arg = (level - g[3]) / g[0];
    if (!(fabs(arg) < 1.0)) return NAN;
    distance = s * ((atanh(arg) - g[2]) / g[1] - c->st[4]); /* the drive's way there, toward the side */
    d0 = s * (u - c->st[4]);
    if (!(distance > d0)) return NAN;
    xb = x0 + (distance - d0);
    db = gap(c, xb, s, first);
    if (db == distance) return xb;
    if (!(db != d0)) return NAN;
    x = xb + (distance - db) * (xb - x0) / (db - d0);
    return isfinite(x) && x > x0 ? x : NAN;
}

/* The current on side s whose output meets the target, nearest start (_search). */
static void search(msma_inverse *c, int s, double start, double step0, double target, int first, double *i_out,
                   double *f_out) {
    const double lo = c->lo, hi = c->hi, htol = c->htol, rtol = c->rtol, xtol = c->xtol;
    double x_min, x_max, x0, f0, best_x, best_f, xl, fl, xr, fr, exl, efl, exr, efr, y_stage0, hint;
    int down_done, up_done, direction, found, edge_found, sweep, it, away, bounded;
    if (s > 0) {
        x_min = lo, x_max = hi;
    } else {
        x_min = -hi, x_max = -lo;
    }
    x0 = pmin(pmax(s * start, x_min), x_max);
    f0 = objective(c, x0, s, target, first);
    if (fabs(f0) <= htol) {
        *i_out = s * x0, *f_out = f0;
        return;
    }
    down_done = x0 <= x_min;
    if (f0 == -INFINITY) {
        /* 2. the side's edge above x0, on the drive alone: probes growing 4x from EDGE_WIDTH xtol (or
         * to where the drive's gap, straight through the last two probes, closes), then edge() */
        double xp = x0, dp = gap(c, x0, s, first), step = EDGE_WIDTH * xtol, x = pmin(x0 + step, x_max), d = dp;
        int on = 0;
        for (it = 0; it < MAX_ITERATIONS; it++) {
            double x_next;
            d = gap(c, x, s, first);
            on = on_side(c, d, s);
            if (on || x >= x_max) break;
            step *= 4.0;
            x_next = x + step;
            if (d > dp) x_next = pmax(x_next, x - d * (x - xp) / (d - dp));
            xp = x, dp = d;
            x = pmin(x_next, x_max);
        }
        if (!on) {
            *i_out = s * x0, *f_out = f0;
            return;
        }
        x0 = edge(c, xp, dp, x, d, s, first);
        f0 = objective(c, x0, s, target, first);
        down_done = 1;
        if (fabs(f0) <= htol) {
            *i_out = s * x0, *f_out = f0;
            return;
        }
    }
    /* 3. probes for a sign change; away from the root of a nondecreasing F only while the thermal
     * stage can still make F fall by |F| before the limit (always with training's strain part on) */
    bounded = !(c->p.has_training && c->tr[4] != 0.0);
    y_stage0 = c->y_stage;
    best_x = x0, best_f = f0;
    up_done = x0 >= x_max;
    direction = f0 < 0.0 ? 1 : -1;
    if (direction < 0 && down_done) direction = 1;
    found = 0;
    edge_found = 0;
    xl = x0, fl = f0, xr = x0, fr = f0;
    exl = x0, efl = f0, exr = x0, efr = f0;
    for (sweep = 0; sweep < 2; sweep++) {
        double xp, fp, step;
        if (sweep == 1) direction = -direction;
        if ((direction > 0 && up_done) || (direction < 0 && down_done)) continue;
        away = direction * f0 > 0.0;
        if (away && bounded && fabs(f0) > thermal_fall(c, y_stage0, s * x0, s * f0, first)) continue;
        xp = x0, fp = f0;
        step = step0;
        /* toward the root after a reversal: the first probe at the dead zone's end, the steps grow
         * from there */
        hint = direction > 0 && !away && (c->st[5] > 0.5) != (s > 0) ? dead_zone_end(c, x0, s, first) : NAN;
        for (;;) {
            double x = direction > 0 ? pmin(xp + step, x_max) : pmax(xp - step, x_min), f;
            if (hint > x) {
                x = pmin(hint, x_max);
            } else {
                step *= 4.0;
            }
            hint = NAN;
            f = objective(c, x, s, target, first);
            if (f == -INFINITY) { /* off the side: a root may lie between its edge and xp when F > 0 at xp */
                if (fp > 0.0 && !edge_found) {
                    edge_found = 1;
                    if (direction > 0) {
                        exl = xp, efl = fp, exr = x, efr = f;
                    } else {
                        exl = x, efl = f, exr = xp, efr = fp;
                    }
                }
                break;
            }
            if ((f < 0.0) != (fp < 0.0)) {
                if (direction > 0) {
                    xl = xp, fl = fp, xr = x, fr = f;
                } else {
                    xl = x, fl = f, xr = xp, fr = fp;
                }
                found = 1;
                break;
            }
            if (magnitude(f) < magnitude(best_f)) best_x = x, best_f = f;
            xp = x, fp = f;
            if (x >= x_max || x <= x_min) break;
            if (away && bounded && fabs(f) > thermal_fall(c, c->y_stage, s * x, s * f0, first)) break;
        }
        if (found) break;
    }
    if (!found && edge_found) { /* no sign change on the side: between its edge and the last point on it */
        double x_on = efr == -INFINITY ? exl : exr, f_on = efr == -INFINITY ? efl : efr;
        double x_off = efr == -INFINITY ? exr : exl, x, f;
        x = edge(c, x_off, gap(c, x_off, s, first), x_on, gap(c, x_on, s, first), s, first);
        if (x == x_on) {
            *i_out = s * x_on, *f_out = f_on;
            return;
        }
        f = objective(c, x, s, target, first);
        if ((f < 0.0) == (f_on < 0.0)) { /* no root between: the point nearer the target */
            if (fabs(f) < fabs(f_on)) {
                *i_out = s * x, *f_out = f;
            } else {
                *i_out = s * x_on, *f_out = f_on;
            }
            return;
        }
        if (x < x_on) {
            xl = x, fl = f, xr = x_on, fr = f_on;
        } else {
            xl = x_on, fl = f_on, xr = x, fr = f;
        }
        found = 1;
    }
    if (!found) {
        *i_out = s * best_x, *f_out = best_f;
        return;
    }
    /* 4. refine the bracket xl < xr: Brent's method (as scipy's brentq), by bisection while an end
     * is off the side (done at EDGE_WIDTH xtol) (_search, _brent_step) */
    {
        double xpre = xl, fpre = fl, xcur = xr, fcur = fr, xblk = xl, fblk = fl, spre = 0.0, scur = 0.0;
        const double delta = 0.5 * xtol;
        for (it = 0; it < MAX_ITERATIONS; it++) {
            double sbis;
            int finite;
            if (fpre != 0.0 && fcur != 0.0 && ((fpre < 0.0) != (fcur < 0.0))) {
                xblk = xpre, fblk = fpre;
                spre = scur = xcur - xpre;
            }
            if (magnitude(fblk) < magnitude(fcur)) { /* xcur: the better end of the bracket */
                xpre = xcur, xcur = xblk, xblk = xpre;
                fpre = fcur, fcur = fblk, fblk = fpre;
            }
            sbis = 0.5 * (xblk - xcur);
            if (magnitude(fcur) <= rtol || fabs(sbis) <= delta) break;
            finite = fcur > -INFINITY && fpre > -INFINITY && fblk > -INFINITY;
            if (!finite && fabs(sbis) <= 0.5 * EDGE_WIDTH * xtol) break;
            brent_step(xpre, fpre, xcur, fcur, xblk, fblk, sbis, delta, finite, &spre, &scur);
            xpre = xcur, fpre = fcur;
            xcur += fabs(scur) > delta ? scur : (sbis > 0.0 ? delta : -delta);
            fcur = objective(c, xcur, s, target, first);
        }
        if (magnitude(fblk) < magnitude(fcur)) {
            *i_out = s * xblk, *f_out = fblk;
        } else {
            *i_out = s * xcur, *f_out = fcur;
        }
    }
}

int msma_inverse_init(msma_inverse *c, const msma_params *p, double lo, double hi, double scale) {
    int status = check_params(p), q, j;
    double rising[4], falling[4];
    if (status != MSMA_OK) return status;
    if (!(isfinite(lo) && isfinite(hi) && lo < hi && isfinite(scale))) return MSMA_BAD_RANGE;
    memset(c, 0, sizeof *c);
    c->p = *p;
    c->lo = lo;
    c->hi = hi;
    c->xtol = 1e-15 * (hi - lo);
    c->rtol = 4.0 * DOUBLE_EPSILON * pmax(1.0, scale); /* rounding of the output */
    c->htol = 16.0 * c->rtol;                          /* a hold (no move) is accepted this close */
    c->ytol = 1e-9 * (1.0 + fabs(scale));
    gpi_coefficients(p, rising, falling, c->g + 8, c->g + 12);
    for (q = 0; q < 4; q++) c->g[q] = rising[q], c->g[4 + q] = falling[q];
    operators(p, c->threshold, c->weight);
    for (j = 0; j < MSMA_N_OPERATORS; j++) c->memory[j] = p->has_initial_state ? held_memory(p, j) : 0.0;
    if (p->has_initial_state) {
        c->st[8] = p->initial_state_memory;
        c->st[14] = p->initial_state_excursion;
    }
    c->tr[0] = p->training_deficit, c->tr[1] = p->training_threshold, c->tr[2] = p->training_travel;
    c->tr[3] = p->training_shape, c->tr[4] = p->training_gain, c->tr[5] = p->training_width;
    if (p->has_creep) {
        c->n_log = p->creep_log_modes;
        c->n_sat = MSMA_CREEP_MODES;
        for (q = 0; q < MSMA_CREEP_MODES; q++) c->creep_tau[q] = p->creep_mode_tau[q];
        for (q = 0; q < MSMA_LOG_CREEP_MAX_MODES; q++) {
            c->creep_tau[MSMA_CREEP_MODES + q] = q < c->n_log ? p->creep_log_tau[q] : 1.0;
        }
        c->cp[0] = p->creep_amplitude, c->cp[1] = MSMA_CREEP_MODES, c->cp[2] = p->creep_log_rate;
        c->cp[3] = c->n_log, c->cp[4] = p->creep_log_hold;
    }
    c->th[0] = p->thermal_tau, c->th[1] = p->thermal_sensitivity, c->th[2] = p->thermal_expansion;
    c->th[3] = REFERENCE_CURRENT, c->th[4] = p->thermal_tau_core, c->th[5] = p->thermal_sensitivity_core;
    c->th[6] = p->thermal_expansion_core;
    c->th[7] = p->has_thermal ? p->thermal_initial : 0.0, c->th[8] = p->has_thermal ? p->thermal_initial_core : 0.0;
    c->previous_step = 0.1 * (hi - lo);
    c->step = -1.0;
    return MSMA_OK;
}

/* The per-step filter coefficients (computed again only when the step changes: the same values). */
static void step_coefficients(msma_inverse *c, double h) {
    const msma_params *p = &c->p;
    double gain, decay;
    int active, q;
    if (h == c->step) return;
    c->step = h;
    filter_coefficients(h, p->has_lag ? p->lag_tau : 0.0, &gain, &decay, &active);
    c->lag_c[0] = gain, c->lag_c[1] = decay, c->lag_c[2] = active ? 1.0 : 0.0;
    if (p->has_creep) {
        for (q = 0; q < c->n_sat + c->n_log; q++) {
            filter_coefficients(h, c->creep_tau[q], &c->creep_gain[q], &c->creep_decay[q], &c->creep_active[q]);
        }
    }
    if (p->has_thermal) {
        filter_coefficients(h, c->th[0], &gain, &decay, &active);
        c->thermal_c[0] = gain, c->thermal_c[1] = decay, c->thermal_c[2] = active ? 1.0 : 0.0;
        filter_coefficients(h, c->th[4], &gain, &decay, &active);
        c->thermal_c[3] = gain, c->thermal_c[4] = decay, c->thermal_c[5] = active ? 1.0 : 0.0;
    }
}

double msma_inverse_step(msma_inverse *c, double t, double target, int *status) {
    const double lo = c->lo, hi = c->hi;
    int first = c->k == 0, pref;
    double start, step0, i_best, f_best, y;
    if (!first) {
        step_coefficients(c, t - c->t_prev);
        if (c->p.has_creep) creep_prepare(c);
    }
    if (first) {
        pref = 1;
        start = lo;
        step0 = 0.1 * (hi - lo);
    } else {
        pref = c->st[5] > 0.5 ? 1 : -1; /* continue on the previous sample's side first */
        start = c->st[0];
        step0 = pmax(2.0 * c->previous_step, 1e-4 * (hi - lo));
    }
    search(c, pref, start, step0, target, first, &i_best, &f_best);
    if (fabs(f_best) > c->htol && !first) {
        double i_other, f_other;
        search(c, -pref, start, step0, target, first, &i_other, &f_other);
        if (fabs(f_other) <= c->htol) {
            i_best = i_other, f_best = f_other;
        } else {
            /* Neither side exact: the side toward the target that falls short along its whole
             * range is driven to its limit (full effort); otherwise the output nearer the target. */
            double f_rise = pref > 0 ? f_best : f_other;
            double f_fall = pref > 0 ? f_other : f_best;
            double toward = target - c->y_prev;
            if (toward > 0.0 && -INFINITY < f_rise && f_rise < 0.0) {
                i_best = hi;
            } else if (toward < 0.0 && -INFINITY < f_fall && f_fall < 0.0) {
                i_best = lo;
            } else if (magnitude(f_other) < magnitude(f_best)) {
                i_best = i_other, f_best = f_other;
            }
        }
    }
    if (!first) c->previous_step = fabs(i_best - c->st[0]);
    y = commit(c, i_best, first);
    c->y = y;
    c->y_prev = y;
    if (fabs(y - target) <= c->ytol) {
        c->status = MSMA_EXACT;
    } else {
        c->status = (i_best <= lo || i_best >= hi) ? MSMA_SATURATED : MSMA_BRANCH;
    }
    if (status) *status = c->status;
    c->t_prev = t;
    c->k += 1;
    return i_best;
}

int msma_inverse_run(const msma_params *p, double lo, double hi, double scale, size_t n, const double *t,
                     const double *target, double *current, double *output, int *status) {
    msma_inverse c;
    size_t k;
    int code = msma_inverse_init(&c, p, lo, hi, scale);
    if (code != MSMA_OK) return code;
    for (k = 0; k < n; k++) {
        current[k] = msma_inverse_step(&c, t[k], target[k], status ? &status[k] : NULL);
        if (output) output[k] = c.y;
    }
    return MSMA_OK;
}

size_t msma_params_size(void) { return sizeof(msma_params); }
size_t msma_forward_size(void) { return sizeof(msma_forward); }
size_t msma_inverse_size(void) { return sizeof(msma_inverse); }
