/*
 * wftool's harness around the FSP uplink's command path — who flies (io/fsp_authority.c)
 * and the timed-command queue (io/fsp_queue.c) of the patch series — compiled with the
 * sources the queue's unit test compiles (the authority, the queue, the freshness gate
 * io/fsp_command.c, the codec, the MSP receiver rx/msp.c) for the Cortex-M7 (an image
 * executed by wftool.analysis.m7).
 *
 * The authority (with the gate and the queue inside) and the FC's state it reads live here,
 * as io/fsp.c keeps them; the PID loop's work is queueHarnessPidLoop(), which does what
 * fspApplyTimedCommands() does (without its check that an FSP port is open), and an FSP
 * task run's work is harnessFspRun(), which does what processUplink() does with the
 * packets decoded (without reading the UART). The rest prepares states to measure them in.
 *
 * SPDX-License-Identifier: GPL-3.0-or-later
 */

#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#include "platform.h"

#include "fc/rc_modes.h"

#include "io/fsp_authority.h"
#include "io/fsp_codec.h"
#include "io/fsp_command.h"
#include "io/fsp_queue.h"

#include "rx/rx.h"

#define HARNESS_TIMEOUT_US  50000       // timedcost.TIMEOUT_US
#define HARNESS_SENDER      0x3A5C71

// what the firmware around the uplink provides
rxRuntimeState_t rxRuntimeState;
static uint32_t harnessMs;

uint32_t millis(void)
{
    return harnessMs;
}

uint32_t micros(void)  // rx/msp.c stamps the MSP receiver's frames with it (Betaflight 2026.6)
{
    return harnessMs * 1000;
}

bool IS_RC_MODE_ACTIVE(boxId_e boxId)
{
    UNUSED(boxId);
    return false;
}

fspAuthority_t harnessAuthority;
uint8_t harnessRcmap[RX_MAPPABLE_CHANNEL_COUNT] = { 0, 1, 3, 2, 4, 5, 6, 7 };  // AETR1234
static fspAuthorityEnv_t harnessEnv;
fspCommand_t harnessCommandBuf;     // a decoded packet, for a measured run
uint8_t harnessScratch[80];         // a packet's wire bytes

static fspAuthorityEnv_t harnessEnvOf(void)
{
    return harnessEnv;
}

static fspCommand_t harnessCommand(uint32_t seq, uint32_t atUs, bool timed)
{
    fspCommand_t cmd;
    memset(&cmd, 0, sizeof(cmd));
    cmd.seq = seq;
    cmd.sender = HARNESS_SENDER;
    cmd.reservedClear = true;
    for (unsigned i = 0; i < FSP_RC_COUNT; i++) {
        cmd.rc[i] = (int16_t)(1000 + 100 * i + seq % 100);
    }
    cmd.timed = timed;
    cmd.atUs = atUs;
    return cmd;
}

// One FSP task run at nowUs that decoded `count` packets, as processUplink() runs them.
static void harnessRun(const fspCommand_t *cmds, unsigned count, uint32_t nowUs)
{
    fspAuthorityBegin(&harnessAuthority, nowUs);
    for (unsigned i = 0; i < count; i++) {
        fspAuthorityAdmit(&harnessAuthority, &harnessEnv, &cmds[i], nowUs);
    }
    fspAuthorityEnd(&harnessAuthority, &harnessEnv, nowUs);
}

// A live uplink at nowUs (two immediate commands handed over; the OBC alone: its link is
// the receiver), an empty queue.
void queueHarnessSetup(uint32_t nowUs)
{
    memset(&harnessEnv, 0, sizeof(harnessEnv));
    harnessEnv.obcReceiver = true;
    harnessEnv.rxSignal = true;
    harnessEnv.rcMinUs = 885;
    harnessEnv.rcMaxUs = 2115;
    harnessEnv.rcmap = harnessRcmap;
    fspAuthorityInit(&harnessAuthority, HARNESS_TIMEOUT_US);
    const fspCommand_t cmds[2] = { harnessCommand(1, 0, false), harnessCommand(2, 0, false) };
    harnessRun(cmds, 2, nowUs);
}

// The FSP task decodes packet `seq` at nowUs into harnessCommandBuf: a timed command due at
// atUs, or (atUs 0) an immediate command. harnessFspRun() then runs the FSP task with it.
void queueHarnessDecode(uint32_t seq, uint32_t atUs)
{
    harnessCommandBuf = harnessCommand(seq, atUs, atUs != 0);
}

// What the FSP task does in a run at nowUs that decoded harnessCommandBuf (count 1) or
// nothing (count 0); returns the authority afterwards.
int harnessFspRun(uint32_t count, uint32_t nowUs)
{
    harnessRun(&harnessCommandBuf, count, nowUs);
    return harnessAuthority.state;
}

// Decode and run, as the FSP task does; returns the timed command's outcome so far (queued
// on time 0, late 1), or -1 if it was not queued.
int queueHarnessTake(uint32_t seq, uint32_t atUs, uint32_t nowUs)
{
    const uint8_t queued = harnessAuthority.queue.count;
    queueHarnessDecode(seq, atUs);
    harnessFspRun(1, nowUs);
    if (harnessAuthority.queue.count != queued + 1) {
        return -1;
    }
    return cmpTimeUs(atUs, nowUs) <= 0 ? FSP_TIMED_LATE : FSP_TIMED_ON_TIME;
}

// The PID loop's work at an iteration at nowUs, as fspApplyTimedCommands() does it.
void queueHarnessPidLoop(uint32_t nowUs)
{
    if (fspAuthorityTimedDue(&harnessAuthority, nowUs)) {
        fspAuthorityApplyDue(&harnessAuthority, harnessEnvOf, nowUs);
    }
}

// rxFrameCheck()'s every call with the MSP receiver: the receiver's signal delay.
int queueHarnessSignalDelay(void)
{
    return fspCommandGateSignalDelayUs(&harnessAuthority.gate);
}

unsigned queueHarnessQueueSize(void)
{
    return sizeof(fspQueue_t);
}

unsigned queueHarnessAuthoritySize(void)
{
    return sizeof(fspAuthority_t);
}

unsigned queueHarnessQueued(void)
{
    return harnessAuthority.queue.count;
}

// The FSP task sends the oldest report; returns its outcome (-1: none).
int queueHarnessPopReport(void)
{
    fspCommandReport_t report;
    return fspQueuePopReport(&harnessAuthority.queue, &report) ? report.outcome : -1;
}

// A report's wire bytes as the FSP task encodes them (its cost per report, besides the UART).
unsigned queueHarnessEncodeReport(uint8_t *wire)
{
    static const fspCommandReport_t report = { 42, 123456, 5000000, 5000062, 0, 1, { 1, 0, 0, 0, 0, 0 } };
    uint8_t packet[FSP_COMMAND_REPORT_PACKET_SIZE];
    return fspFramePacket(wire, packet, fspEncodeCommandReport(packet, &report));
}

// An uplink status's wire bytes as the FSP task encodes them (every 100 ms, and at a change).
unsigned queueHarnessEncodeStatus(uint8_t *wire)
{
    static const fspUplinkStatus_t status = { 1234, 2100000, 1233, 1, 0, 2, 50, 0x13, 0, 0, FSP_AUTHORITY_ENGAGED, FSP_EXIT_NONE, 500, 0, HARNESS_SENDER, 0, 0, 0, 885, 2115 };
    uint8_t packet[FSP_UPLINK_STATUS_PACKET_SIZE];
    return fspFramePacket(wire, packet, fspEncodeUplinkStatus(packet, &status));
}
