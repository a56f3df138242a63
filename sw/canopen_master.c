/* ============================================================================================== */
/* canopen_master.c                                                                               */
/* Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)              */
/* SPDX-License-Identifier: Apache-2.0                                                            */
/* ============================================================================================== */
/*
 * C HAL of the CANopen master (see canopen_master.h and docs/c_driver.md). Register accesses
 * only through ctx->wr / ctx->rd, word addresses and fields from the generated
 * canopen_master_regs.h.
 */

#include "canopen_master.h"

#include <string.h>

#define WR(a, v) ctx->wr(ctx, (uint32_t)(a), (uint32_t)(v))
#define RD(a) ctx->rd(ctx, (uint32_t)(a))

#define SDO_CHANNELS_FIELD_MAX 4u
#define PDO_CHANNELS_FIELD_MAX 32u
#define EMCY_DRAIN_MAX 128u

static uint32_t le32(const uint8_t *p, size_t n)
{
    uint32_t v = 0;
    size_t i;
    for (i = 0; i < n && i < 4u; i++) {
        v |= (uint32_t)p[i] << (8u * i);
    }
    return v;
}

static void put_le32(uint8_t *p, uint32_t v, size_t n)
{
    size_t i;
    for (i = 0; i < n && i < 4u; i++) {
        p[i] = (uint8_t)(v >> (8u * i));
    }
}

static void idle(cm_ctx_t *ctx)
{
    if (ctx->idle != NULL) {
        ctx->idle(ctx);
    }
}

/* ---------------------------------------------------------------- set-up, identification */
void cm_setup(cm_ctx_t *ctx, cm_wr_fn wr, cm_rd_fn rd, cm_idle_fn idle_fn, void *user)
{
    memset(ctx, 0, sizeof(*ctx));
    ctx->wr = wr;
    ctx->rd = rd;
    ctx->idle = idle_fn;
    ctx->user = user;
    ctx->max_polls = CM_DEFAULT_MAX_POLLS;
    ctx->sdo_chan = 0xFFu;
}

size_t cm_ctx_size(void)
{
    return sizeof(cm_ctx_t);
}

cm_status_t cm_identify(cm_ctx_t *ctx)
{
    /* the header's own version: a variable, not a constant expression, so that the minor
       comparison stays free of "always false" warnings when the header's minor is 0 */
    static const uint32_t hdr_version = CM_VERSION_RESET;
    uint32_t id = RD(CM_REG_ID);
    uint32_t ver, info;
    if (id != CM_ID_RESET) {
        return CM_ERR_ID;
    }
    ver = RD(CM_REG_VERSION);
    ctx->version = ver;
    if (CM_GET(CM_VERSION_MAJOR, ver) != CM_GET(CM_VERSION_MAJOR, hdr_version)
        || CM_GET(CM_VERSION_MINOR, ver) < CM_GET(CM_VERSION_MINOR, hdr_version)) {
        return CM_ERR_VERSION;
    }
    ctx->n_sdo = (uint8_t)CM_GET(CM_SDO_SEL_CHANNELS, RD(CM_REG_SDO_SEL));
    ctx->sdo_chan = 0xFFu;
    info = RD(CM_REG_PDO_INFO);
    ctx->n_tpdo = (uint8_t)CM_GET(CM_PDO_INFO_N_TPDO, info);
    ctx->n_rpdo = (uint8_t)CM_GET(CM_PDO_INFO_N_RPDO, info);
    return CM_OK;
}

cm_status_t cm_init(cm_ctx_t *ctx, uint32_t irq_enable)
{
    cm_status_t st = cm_identify(ctx);
    uint32_t k, status = 0;
    if (st != CM_OK) {
        return st;
    }
    for (k = 0; k < ctx->max_polls; k++) {
        status = RD(CM_REG_STATUS);
        if (status & CM_STATUS_INIT_DONE_MASK) {
            WR(CM_REG_IRQ_ENABLE, irq_enable);
            return CM_OK;
        }
        idle(ctx);
    }
    return (status & CM_STATUS_INIT_FAIL_MASK) ? CM_ERR_INIT : CM_ERR_TIMEOUT;
}

/* ---------------------------------------------------------------- NMT, SYNC */
cm_status_t cm_nmt(cm_ctx_t *ctx, uint8_t cs, uint8_t node)
{
    uint32_t k;
    if ((cs != CM_NMT_START && cs != CM_NMT_STOP && cs != CM_NMT_PREOP
         && cs != CM_NMT_RESET_NODE && cs != CM_NMT_RESET_COMM) || node > 127u) {
        return CM_ERR_ARG;
    }
    for (k = 0; RD(CM_REG_NMT_CMD) & CM_NMT_CMD_NMT_BUSY_MASK; k++) {
        if (k + 1u >= ctx->max_polls) {
            return CM_ERR_TIMEOUT;
        }
        idle(ctx);
    }
    WR(CM_REG_NMT_CMD, CM_PUT(CM_NMT_CMD_CS, cs) | CM_PUT(CM_NMT_CMD_NODE, node));
    /* REFUSED describes this write: first read right after it */
    return (RD(CM_REG_NMT_CMD) & CM_NMT_CMD_REFUSED_MASK) ? CM_ERR_REFUSED : CM_OK;
}

cm_status_t cm_sync_config(cm_ctx_t *ctx, uint32_t period_us, uint8_t overflow,
                           uint32_t window_us, int enable)
{
    uint32_t ctrl;
    if (overflow == 1u || overflow > 240u) {
        return CM_ERR_ARG;
    }
    WR(CM_REG_SYNC_PERIOD_US, CM_PUT(CM_SYNC_PERIOD_US_VALUE, period_us));
    WR(CM_REG_SYNC_OVERFLOW, CM_PUT(CM_SYNC_OVERFLOW_VALUE, overflow));
    WR(CM_REG_SYNC_WINDOW_US, CM_PUT(CM_SYNC_WINDOW_US_VALUE, window_us));
    ctrl = RD(CM_REG_CTRL) & (CM_CTRL_SYNC_EN_MASK | CM_CTRL_OMNI_MASK); /* pulses read 0 */
    ctrl = enable ? (ctrl | CM_CTRL_SYNC_EN_MASK) : (ctrl & ~CM_CTRL_SYNC_EN_MASK);
    WR(CM_REG_CTRL, ctrl);
    return CM_OK;
}

/* ---------------------------------------------------------------- SDO */
static cm_status_t sdo_select(cm_ctx_t *ctx, uint8_t chan)
{
    uint32_t n = ctx->n_sdo ? ctx->n_sdo : SDO_CHANNELS_FIELD_MAX;
    if (chan >= n) {
        return CM_ERR_ARG;
    }
    if (ctx->sdo_chan != chan) {
        WR(CM_REG_SDO_SEL, CM_PUT(CM_SDO_SEL_CHAN, chan));
        ctx->sdo_chan = chan;
    }
    return CM_OK;
}

void cm_sdo_set_timeout(cm_ctx_t *ctx, uint16_t timeout_ms)
{
    WR(CM_REG_SDO_TIMEOUT_MS, CM_PUT(CM_SDO_TIMEOUT_MS_VALUE, timeout_ms));
}

static cm_status_t sdo_command(cm_ctx_t *ctx, uint8_t node, uint16_t index, uint8_t sub,
                               int upload, size_t size)
{
    WR(CM_REG_SDO_OBJ, CM_PUT(CM_SDO_OBJ_INDEX, index) | CM_PUT(CM_SDO_OBJ_SUBINDEX, sub));
    WR(CM_REG_SDO_CMD, CM_PUT(CM_SDO_CMD_NODE, node) | CM_PUT(CM_SDO_CMD_UPLOAD, upload ? 1u : 0u)
                       | CM_PUT(CM_SDO_CMD_SIZE, size));
    /* REFUSED describes this write: first read right after it, never while polling DONE */
    return (RD(CM_REG_SDO_CMD) & CM_SDO_CMD_REFUSED_MASK) ? CM_ERR_REFUSED : CM_OK;
}

cm_status_t cm_sdo_start_download(cm_ctx_t *ctx, uint8_t chan, uint8_t node, uint16_t index,
                                  uint8_t sub, const uint8_t *data, size_t len)
{
    size_t w;
    cm_status_t st;
    if (node < 1u || node > 127u || data == NULL || len < 1u || len > CM_SDO_BUF_BYTES) {
        return CM_ERR_ARG;
    }
    st = sdo_select(ctx, chan);
    if (st != CM_OK) {
        return st;
    }
    for (w = 0; 4u * w < len; w++) {
        WR(CM_REG_SDO_BUF_W(w), le32(data + 4u * w, len - 4u * w));
    }
    return sdo_command(ctx, node, index, sub, 0, len);
}

cm_status_t cm_sdo_start_upload(cm_ctx_t *ctx, uint8_t chan, uint8_t node, uint16_t index,
                                uint8_t sub)
{
    cm_status_t st;
    if (node < 1u || node > 127u) {
        return CM_ERR_ARG;
    }
    st = sdo_select(ctx, chan);
    if (st != CM_OK) {
        return st;
    }
    return sdo_command(ctx, node, index, sub, 1, 0);
}

cm_status_t cm_sdo_poll(cm_ctx_t *ctx, uint8_t chan, cm_sdo_result_t *res)
{
    uint32_t cmd;
    cm_status_t st = sdo_select(ctx, chan);
    if (st != CM_OK) {
        return st;
    }
    cmd = RD(CM_REG_SDO_CMD);
    if (!(cmd & CM_SDO_CMD_DONE_MASK)) {
        return CM_PENDING;
    }
    if (res != NULL) {
        res->size = CM_GET(CM_SDO_CMD_XFER_SIZE, cmd);
        res->abort_code = 0;
        res->abort_sent = 0;
    }
    if (cmd & CM_SDO_CMD_ERROR_MASK) {
        uint32_t code = RD(CM_REG_SDO_ABORT);
        if (res != NULL) {
            res->abort_code = code;
            res->abort_sent = (uint8_t)((cmd & CM_SDO_CMD_ABORT_SENT_MASK) ? 1u : 0u);
        }
        return CM_ERR_ABORT;
    }
    return CM_OK;
}

cm_status_t cm_sdo_read_buf(cm_ctx_t *ctx, uint8_t chan, uint8_t *buf, size_t n)
{
    size_t w;
    cm_status_t st;
    if (n > CM_SDO_BUF_BYTES || (buf == NULL && n > 0u)) {
        return CM_ERR_ARG;
    }
    st = sdo_select(ctx, chan);
    if (st != CM_OK) {
        return st;
    }
    for (w = 0; 4u * w < n; w++) {
        put_le32(buf + 4u * w, RD(CM_REG_SDO_BUF_W(w)), n - 4u * w);
    }
    return CM_OK;
}

static cm_status_t sdo_wait(cm_ctx_t *ctx, uint8_t chan, cm_sdo_result_t *res)
{
    uint32_t k;
    for (k = 0; k < ctx->max_polls; k++) {
        cm_status_t st = cm_sdo_poll(ctx, chan, res);
        if (st != CM_PENDING) {
            return st;
        }
        idle(ctx);
    }
    return CM_ERR_TIMEOUT;
}

cm_status_t cm_sdo_download(cm_ctx_t *ctx, uint8_t chan, uint8_t node, uint16_t index,
                            uint8_t sub, const uint8_t *data, size_t len, cm_sdo_result_t *res)
{
    cm_sdo_result_t local;
    cm_status_t st = cm_sdo_start_download(ctx, chan, node, index, sub, data, len);
    if (st != CM_OK) {
        return st;
    }
    return sdo_wait(ctx, chan, res != NULL ? res : &local);
}

cm_status_t cm_sdo_upload(cm_ctx_t *ctx, uint8_t chan, uint8_t node, uint16_t index,
                          uint8_t sub, uint8_t *buf, size_t cap, size_t *len,
                          cm_sdo_result_t *res)
{
    cm_sdo_result_t local;
    cm_sdo_result_t *r = res != NULL ? res : &local;
    size_t n;
    cm_status_t st;
    if (buf == NULL && cap > 0u) {
        return CM_ERR_ARG;
    }
    st = cm_sdo_start_upload(ctx, chan, node, index, sub);
    if (st == CM_OK) {
        st = sdo_wait(ctx, chan, r);
    }
    if (st != CM_OK) {
        return st;
    }
    n = r->size < cap ? r->size : cap;
    n = n < CM_SDO_BUF_BYTES ? n : CM_SDO_BUF_BYTES;
    st = cm_sdo_read_buf(ctx, chan, buf, n);
    if (len != NULL) {
        *len = n;
    }
    if (st == CM_OK && r->size > cap) {
        st = CM_ERR_SIZE;
    }
    return st;
}

/* ---------------------------------------------------------------- configuration list */
cm_status_t cm_acfg_load(cm_ctx_t *ctx, const cm_acfg_entry_t *entries, size_t n, uint8_t first)
{
    size_t i;
    if ((entries == NULL && n > 0u) || (size_t)first + n > 255u) {
        return CM_ERR_ARG;
    }
    for (i = 0; i < n; i++) {
        const cm_acfg_entry_t *e = &entries[i];
        if (e->node < 1u || e->node > 127u || e->size < 1u || e->size > 4u) {
            return CM_ERR_ARG;
        }
    }
    for (i = 0; i <= n; i++) {
        uint32_t entry = (uint32_t)first + (uint32_t)i;
        if (i < n) {
            const cm_acfg_entry_t *e = &entries[i];
            WR(CM_REG_ACFG_ENTRY, CM_PUT(CM_ACFG_ENTRY_ENTRY, entry)
                                  | CM_PUT(CM_ACFG_ENTRY_NODE, e->node)
                                  | CM_PUT(CM_ACFG_ENTRY_SIZE, e->size));
            WR(CM_REG_ACFG_OBJ, CM_PUT(CM_ACFG_OBJ_INDEX, e->index)
                                | CM_PUT(CM_ACFG_OBJ_SUBINDEX, e->sub));
            WR(CM_REG_ACFG_VALUE, e->value);
        } else { /* end of the list: node 0 */
            WR(CM_REG_ACFG_ENTRY, CM_PUT(CM_ACFG_ENTRY_ENTRY, entry));
            WR(CM_REG_ACFG_VALUE, 0u);
        }
    }
    return CM_OK;
}

cm_status_t cm_acfg_start(cm_ctx_t *ctx, int start_nodes)
{
    WR(CM_REG_ACFG_CTRL, CM_ACFG_CTRL_START_MASK | (start_nodes ? CM_ACFG_CTRL_START_NODES_MASK : 0u));
    return (RD(CM_REG_ACFG_STATUS) & CM_ACFG_STATUS_REFUSED_MASK) ? CM_ERR_REFUSED : CM_OK;
}

cm_status_t cm_acfg_poll(cm_ctx_t *ctx, cm_acfg_result_t *res)
{
    uint32_t st = RD(CM_REG_ACFG_STATUS);
    if (!(st & CM_ACFG_STATUS_DONE_MASK) || (st & CM_ACFG_STATUS_BUSY_MASK)) {
        return CM_PENDING;
    }
    if (res != NULL) {
        res->nodes_ok = (uint8_t)CM_GET(CM_ACFG_STATUS_NODES_OK, st);
        res->nodes_fail = (uint8_t)CM_GET(CM_ACFG_STATUS_NODES_FAIL, st);
    }
    return CM_GET(CM_ACFG_STATUS_NODES_FAIL, st) ? CM_ERR_CONFIG : CM_OK;
}

cm_status_t cm_acfg_run(cm_ctx_t *ctx, int start_nodes, cm_acfg_result_t *res)
{
    uint32_t k;
    cm_status_t st = cm_acfg_start(ctx, start_nodes);
    if (st != CM_OK) {
        return st;
    }
    for (k = 0; k < ctx->max_polls; k++) {
        st = cm_acfg_poll(ctx, res);
        if (st != CM_PENDING) {
            return st;
        }
        idle(ctx);
    }
    return CM_ERR_TIMEOUT;
}

cm_status_t cm_acfg_failure(cm_ctx_t *ctx, uint8_t k, uint8_t *node, uint8_t *entry,
                            uint32_t *abort_code)
{
    uint32_t f, code;
    if (k > CM_GET(CM_ACFG_FAIL_SEL_INDEX, CM_ACFG_FAIL_SEL_INDEX_MASK)) {
        return CM_ERR_ARG;
    }
    WR(CM_REG_ACFG_FAIL_SEL, CM_PUT(CM_ACFG_FAIL_SEL_INDEX, k));
    f = RD(CM_REG_ACFG_FAIL);
    code = RD(CM_REG_ACFG_ABORT);
    if (node != NULL) {
        *node = (uint8_t)CM_GET(CM_ACFG_FAIL_NODE, f);
    }
    if (entry != NULL) {
        *entry = (uint8_t)CM_GET(CM_ACFG_FAIL_ENTRY, f);
    }
    if (abort_code != NULL) {
        *abort_code = code;
    }
    return CM_OK;
}

/* ---------------------------------------------------------------- PDO */
static cm_status_t pdo_check(cm_ctx_t *ctx, uint8_t ch, int rpdo, uint8_t dlc)
{
    uint32_t n = rpdo ? ctx->n_rpdo : ctx->n_tpdo;
    if (n == 0u) {
        n = PDO_CHANNELS_FIELD_MAX;
    }
    return (ch >= n || dlc > 8u) ? CM_ERR_ARG : CM_OK;
}

static void pdo_select(cm_ctx_t *ctx, uint8_t ch, int rpdo, int ack)
{
    WR(CM_REG_PDO_SEL, CM_PUT(CM_PDO_SEL_CH, ch) | CM_PUT(CM_PDO_SEL_RPDO, rpdo ? 1u : 0u)
                       | CM_PUT(CM_PDO_SEL_ACK, ack ? 1u : 0u));
}

cm_status_t cm_tpdo_config(cm_ctx_t *ctx, uint8_t ch, uint16_t cob_id, uint8_t dlc, uint8_t tt,
                           uint32_t flags, uint16_t inhibit_100us)
{
    if (pdo_check(ctx, ch, 0, dlc) != CM_OK || cob_id > 0x7FFu || (tt >= 241u && tt <= 251u)) {
        return CM_ERR_ARG;
    }
    pdo_select(ctx, ch, 0, 0);
    WR(CM_REG_PDO_INHIBIT, CM_PUT(CM_PDO_INHIBIT_TIME_100US, inhibit_100us));
    WR(CM_REG_PDO_CFG, CM_PUT(CM_PDO_CFG_COB_ID, cob_id)
                       | CM_PUT(CM_PDO_CFG_RTR, (flags & CM_TPDO_RTR_ALLOWED) ? 1u : 0u)
                       | CM_PDO_CFG_VALID_MASK | CM_PUT(CM_PDO_CFG_DLC, dlc)
                       | CM_PUT(CM_PDO_CFG_TT, tt));
    return CM_OK;
}

cm_status_t cm_rpdo_config(cm_ctx_t *ctx, uint8_t ch, uint16_t cob_id, uint8_t dlc, uint8_t tt,
                           int rtr_poll)
{
    if (pdo_check(ctx, ch, 1, dlc) != CM_OK || cob_id > 0x7FFu) {
        return CM_ERR_ARG;
    }
    pdo_select(ctx, ch, 1, 0);
    WR(CM_REG_PDO_CFG, CM_PUT(CM_PDO_CFG_COB_ID, cob_id)
                       | CM_PUT(CM_PDO_CFG_RTR, rtr_poll ? 1u : 0u) | CM_PDO_CFG_VALID_MASK
                       | CM_PUT(CM_PDO_CFG_DLC, dlc) | CM_PUT(CM_PDO_CFG_TT, tt));
    return CM_OK;
}

cm_status_t cm_tpdo_set(cm_ctx_t *ctx, uint8_t ch, const uint8_t *data, size_t len, int commit,
                        int trigger)
{
    uint8_t raw[8];
    if (pdo_check(ctx, ch, 0, 0) != CM_OK || len > 8u || (data == NULL && len > 0u)) {
        return CM_ERR_ARG;
    }
    memset(raw, 0, sizeof(raw));
    if (len > 0u) {
        memcpy(raw, data, len);
    }
    pdo_select(ctx, ch, 0, 0);   /* loads the staging register (replaced in full below) */
    WR(CM_REG_PDO_DATA_LO, le32(raw, 4));
    WR(CM_REG_PDO_DATA_HI, le32(raw + 4, 4));
    if (commit || trigger) {
        WR(CM_REG_PDO_CMD, CM_PUT(CM_PDO_CMD_COMMIT, commit ? 1u : 0u)
                           | CM_PUT(CM_PDO_CMD_TRIGGER, trigger ? 1u : 0u));
    }
    return CM_OK;
}

int cm_tpdo_pending(cm_ctx_t *ctx, uint8_t ch)
{
    return (ch < 32u && (RD(CM_REG_PDO_TX_PENDING) >> ch) & 1u) ? 1 : 0;
}

cm_status_t cm_rpdo_get(cm_ctx_t *ctx, uint8_t ch, int ack, cm_rpdo_t *out)
{
    uint32_t cfg, lo, hi, cmd, seq, err;
    uint8_t dlc;
    if (pdo_check(ctx, ch, 1, 0) != CM_OK || out == NULL) {
        return CM_ERR_ARG;
    }
    pdo_select(ctx, ch, 1, ack);  /* the snapshot: one consistent reception */
    cfg = RD(CM_REG_PDO_CFG);
    lo = RD(CM_REG_PDO_DATA_LO);
    hi = RD(CM_REG_PDO_DATA_HI);
    cmd = RD(CM_REG_PDO_CMD);
    seq = RD(CM_REG_PDO_SEQ);
    err = RD(CM_REG_PDO_ERR);
    dlc = (uint8_t)CM_GET(CM_PDO_CFG_DLC, cfg);
    put_le32(out->data, lo, 4);
    put_le32(out->data + 4, hi, 4);
    if (dlc < 8u) {
        memset(out->data + dlc, 0, 8u - dlc);
    }
    out->dlc = dlc;
    out->is_new = (uint8_t)CM_GET(CM_PDO_CMD_NEW, cmd);
    out->seq = (uint16_t)CM_GET(CM_PDO_SEQ_SEQ, seq);
    out->sync_count = (uint8_t)CM_GET(CM_PDO_SEQ_SYNC_COUNT, seq);
    out->len_err = (uint16_t)CM_GET(CM_PDO_ERR_LEN_ERR, err);
    out->missed = (uint16_t)CM_GET(CM_PDO_ERR_MISSED, err);
    return CM_OK;
}

uint32_t cm_rpdo_new(cm_ctx_t *ctx)
{
    return RD(CM_REG_PDO_RX_NEW);
}

/* ---------------------------------------------------------------- node supervision */
cm_status_t cm_node_config(cm_ctx_t *ctx, uint8_t slot, uint8_t node_id, uint8_t mode,
                           uint16_t time_ms, uint8_t life_factor, uint32_t flags)
{
    if (slot >= CM_NODE_SLOTS_MAX || node_id > 127u || mode > CM_NODE_MODE_GUARDING) {
        return CM_ERR_ARG;
    }
    WR(CM_REG_NODE_TIME_SLOT(slot), CM_PUT(CM_NODE_TIME_TIME_MS, time_ms)
                                    | CM_PUT(CM_NODE_TIME_LIFE_FACTOR, life_factor));
    WR(CM_REG_NODE_CFG_SLOT(slot),
       CM_PUT(CM_NODE_CFG_NODE_ID, node_id) | CM_PUT(CM_NODE_CFG_MODE, mode)
       | CM_PUT(CM_NODE_CFG_AUTOSTART, (flags & CM_NODE_AUTOSTART) ? 1u : 0u)
       | CM_PUT(CM_NODE_CFG_RESET_ON_LOSS, (flags & CM_NODE_RESET_ON_LOSS) ? 1u : 0u));
    return CM_OK;
}

cm_status_t cm_node_status(cm_ctx_t *ctx, uint8_t slot, cm_node_status_t *out)
{
    uint32_t st;
    if (slot >= CM_NODE_SLOTS_MAX || out == NULL) {
        return CM_ERR_ARG;
    }
    st = RD(CM_REG_NODE_STATUS_SLOT(slot));
    out->nmt_state = (uint8_t)CM_GET(CM_NODE_STATUS_NMT_STATE, st);
    out->alive = (uint8_t)CM_GET(CM_NODE_STATUS_ALIVE, st);
    out->lost = (uint8_t)CM_GET(CM_NODE_STATUS_LOST, st);
    out->toggle_err = (uint8_t)CM_GET(CM_NODE_STATUS_TOGGLE_ERR, st);
    out->bootup = (uint8_t)CM_GET(CM_NODE_STATUS_BOOTUP, st);
    out->last_ms = RD(CM_REG_NODE_LAST_MS_SLOT(slot));
    return CM_OK;
}

cm_status_t cm_node_clear(cm_ctx_t *ctx, uint8_t slot)
{
    if (slot >= CM_NODE_SLOTS_MAX) {
        return CM_ERR_ARG;
    }
    WR(CM_REG_NODE_STATUS_SLOT(slot),
       CM_NODE_STATUS_LOST_MASK | CM_NODE_STATUS_TOGGLE_ERR_MASK | CM_NODE_STATUS_BOOTUP_MASK);
    return CM_OK;
}

/* ---------------------------------------------------------------- EMCY, interrupts */
cm_status_t cm_emcy_pop(cm_ctx_t *ctx, cm_emcy_t *out)
{
    uint32_t st, lo, hi;
    if (out == NULL) {
        return CM_ERR_ARG;
    }
    st = RD(CM_REG_EMCY_STATUS);
    if (CM_GET(CM_EMCY_STATUS_COUNT, st) == 0u) {
        return CM_ERR_EMPTY;
    }
    out->node = (uint8_t)CM_GET(CM_EMCY_NODE_NODE, RD(CM_REG_EMCY_NODE));
    lo = RD(CM_REG_EMCY_DATA_LO);
    hi = RD(CM_REG_EMCY_DATA_HI);
    out->time_ms = RD(CM_REG_EMCY_TIME_MS);
    WR(CM_REG_EMCY_POP, 0u);
    put_le32(out->data, lo, 4);
    put_le32(out->data + 4, hi, 4);
    out->error_code = (uint16_t)(out->data[0] | (uint16_t)out->data[1] << 8);
    out->error_register = out->data[2];
    out->lost = (uint8_t)CM_GET(CM_EMCY_STATUS_LOST, st);
    return CM_OK;
}

void cm_irq_enable(cm_ctx_t *ctx, uint32_t mask)
{
    WR(CM_REG_IRQ_ENABLE, mask);
}

uint32_t cm_irq_handler(cm_ctx_t *ctx)
{
    uint32_t pending = RD(CM_REG_IRQ_STATUS) & RD(CM_REG_IRQ_ENABLE);
    uint32_t bit;
    if (pending == 0u) {
        return 0u;
    }
    WR(CM_REG_IRQ_STATUS, pending);  /* W1C first: an event during the dispatch sets it again */
    if ((pending & CM_IRQ_STATUS_EMCY_MASK) && ctx->on_emcy != NULL) {
        cm_emcy_t e;
        uint32_t k;
        for (k = 0; k < EMCY_DRAIN_MAX && cm_emcy_pop(ctx, &e) == CM_OK; k++) {
            ctx->on_emcy(ctx, &e);
        }
    }
    for (bit = 0; bit < CM_IRQ_SOURCES; bit++) {
        if ((pending >> bit) & 1u && ctx->on_irq[bit] != NULL) {
            ctx->on_irq[bit](ctx, 1u << bit);
        }
    }
    return pending;
}
