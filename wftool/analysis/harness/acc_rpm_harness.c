/*
 * wftool's harness around the Weitflug accelerometer RPM filter
 * (src/main/flight/acc_rpm_filter.c of the patch series), compiled together
 * with that file and Betaflight's common/filter.c and common/maths.c, for the
 * host (a shared library loaded by wftool.analysis.harness) and for the
 * Cortex-M7 (an image executed by wftool.analysis.m7).
 *
 * Only plain entry points live here: the filter code itself is the firmware's,
 * called exactly as accRpmFilterApply() calls it.
 *
 * SPDX-License-Identifier: GPL-3.0-or-later
 */

#include <stdint.h>

#include "platform.h"

#include "common/filter.h"
#include "common/vector.h"

#include "flight/acc_rpm_filter.h"

// settings[]: the accRpmFilterConfig_t fields as int32, in CLI units
enum {
    SETTING_HARMONICS,
    SETTING_WEIGHT_1,
    SETTING_WEIGHT_2,
    SETTING_WEIGHT_3,
    SETTING_MIN_HZ,
    SETTING_FADE_RANGE_HZ,
    SETTING_Q,
    SETTING_COUNT
};

#define COEFFICIENTS_PER_NOTCH 6  // b0, b1, b2, a1, a2, weight: the notch as a biquad

unsigned accHarnessFilterSize(void)
{
    return sizeof(accRpmFilter_t);
}

unsigned accHarnessHarmonicsMax(void)
{
    return ACC_RPM_FILTER_HARMONICS_MAX;
}

// Set the filter up as accRpmFilterInit() does with bidirectional DShot; returns whether it is active.
int accHarnessSetup(accRpmFilter_t *filter, const int32_t *settings, unsigned sampleRateHz, int motorCount)
{
    accRpmFilterConfig_t config = {
        .acc_rpm_filter_harmonics = settings[SETTING_HARMONICS],
        .acc_rpm_filter_weights = { settings[SETTING_WEIGHT_1], settings[SETTING_WEIGHT_2], settings[SETTING_WEIGHT_3] },
        .acc_rpm_filter_min_hz = settings[SETTING_MIN_HZ],
        .acc_rpm_filter_fade_range_hz = settings[SETTING_FADE_RANGE_HZ],
        .acc_rpm_filter_q = settings[SETTING_Q],
    };
    accRpmFilterSetup(filter, &config, sampleRateHz, motorCount);
    return accRpmFilterIsActive(filter);
}

// One accelerometer sample, as accRpmFilterApply() handles it: new motor frequencies, then the notches.
void accHarnessStep(accRpmFilter_t *filter, const float *motorHz, float *xyz)
{
    vector3_t value = { .v = { xyz[0], xyz[1], xyz[2] } };
    if (accRpmFilterIsActive(filter)) {
        accRpmFilterSetMotorFrequencies(filter, motorHz);
        accRpmFilterProcess(filter, &value);
    }
    xyz[0] = value.x;
    xyz[1] = value.y;
    xyz[2] = value.z;
}

// The notches in use, motor-major, then harmonic: [motor][harmonic][b0, b1, b2, a1, a2, weight];
// harmonics the filter skips (weight 0) read weight 0. Each rpmNotch_t (a state-variable filter
// in TPT form: g = tan(pi f / fs) as f, a1 = 1 / (1 + g (g + k)), k = 1 / Q, wq = k * weight)
// is the bilinear transform of the analog notch (s^2 + 1) / (s^2 + k s + 1) prewarped at f,
// so its transfer function is the biquad written here: output = weight * notch + (1 - weight)
// * input, as Betaflight's weighted biquads had it.
int accHarnessCoefficients(const accRpmFilter_t *filter, float *out)
{
    const float k = 1.0f / filter->q;
    int count = 0;
    for (int motor = 0; motor < filter->motorCount; motor++) {
        for (int n = 0; n < filter->numHarmonics; n++) {
            const rpmNotch_t *notch = &filter->notch[motor][n];
            const float g2 = notch->f * notch->f;
            float *c = &out[count * COEFFICIENTS_PER_NOTCH];
            c[0] = (1.0f + g2) * notch->a1;
            c[1] = 2.0f * (g2 - 1.0f) * notch->a1;
            c[2] = c[0];
            c[3] = c[1];
            c[4] = (1.0f - k * notch->f + g2) * notch->a1;
            c[5] = filter->weights[n] > 0.0f ? notch->wq / k : 0.0f;
            count++;
        }
    }
    return count;
}
