/* ============================================================================================== */
/* canopen_master.h                                                                               */
/* Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)              */
/* SPDX-License-Identifier: Apache-2.0                                                            */
/* ============================================================================================== */
/*
 * C HAL of the CANopen master's host interface (canopen_host_regs). Every register access goes
 * through the two callbacks of the context, wr(ctx, word_addr, value) and rd(ctx, word_addr),
 * with the WORD addresses of canopen_master_regs.h, so the same code runs on a Nios II
 * (IOWR_32DIRECT(BASE, 4 * a, v)), on an HPS through a bridge, or on a host talking to a
 * simulation. C99, no malloc, no libc beyond stdint/stddef/string; not reentrant (one context,
 * one caller at a time: the ISR helper cm_irq_handler must not interrupt another call on the
 * same context, or the caller disables the core's interrupt around its calls).
 *
 * Rules the HAL follows (docs/c_driver.md, docs/host_guide.md):
 *  - REFUSED (NMT_CMD, SDO_CMD, ACFG_STATUS) describes the LAST write to that command register
 *    only: set by a refused write, cleared by the next accepted one. The HAL checks it in its
 *    first read right after its own command write and never while polling BUSY/DONE.
 *  - SDO: completion is SDO_CMD.DONE (cleared by the start), never BUSY.
 *  - TPDO: PDO_SEL loads the staging register, DATA_LO/HI + PDO_CMD.COMMIT replace all 8 bytes
 *    at once (at the next SYNC for TT 0..252: no torn frame). RPDO: PDO_SEL takes one
 *    consistent snapshot (data, SEQ, SYNC count, NEW), ACK clears NEW in the same cycle.
 *  - Every blocking call polls at most ctx->max_polls times (ctx->idle between two polls) and
 *    returns CM_ERR_TIMEOUT then: nothing loops forever.
 */

#ifndef CANOPEN_MASTER_H
#define CANOPEN_MASTER_H

#include <stddef.h>
#include <stdint.h>

#include "canopen_master_regs.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Status codes: 0 success, > 0 not finished yet (polled calls), < 0 error. */
typedef enum {
    CM_OK = 0,
    CM_PENDING = 1,        /**< polled call: not finished yet, call again */
    CM_ERR_ARG = -1,       /**< an argument out of range: nothing written */
    CM_ERR_ID = -2,        /**< ID does not read "CO01": not this core, or a bus fault */
    CM_ERR_VERSION = -3,   /**< register map version: other major, or older minor */
    CM_ERR_TIMEOUT = -4,   /**< the poll bound (ctx->max_polls) was reached */
    CM_ERR_REFUSED = -5,   /**< the core refused the command write: nothing was sent */
    CM_ERR_ABORT = -6,     /**< SDO transfer aborted: abort code in the result */
    CM_ERR_INIT = -7,      /**< STATUS.INIT_FAIL: the CAN controller is not initialised */
    CM_ERR_EMPTY = -8,     /**< EMCY FIFO empty */
    CM_ERR_CONFIG = -9,    /**< configuration list finished with failing nodes */
    CM_ERR_SIZE = -10      /**< SDO upload longer than the caller's buffer */
} cm_status_t;

typedef struct cm_ctx cm_ctx_t;

/** Register access: word address of canopen_master_regs.h (CM_REG_*), 32-bit data. */
typedef void (*cm_wr_fn)(cm_ctx_t *ctx, uint32_t word_addr, uint32_t value);
typedef uint32_t (*cm_rd_fn)(cm_ctx_t *ctx, uint32_t word_addr);
/** Called between two polls of a blocking call (e.g. usleep(10)); may be NULL. */
typedef void (*cm_idle_fn)(cm_ctx_t *ctx);

/** One EMCY message (FIFO head). */
typedef struct {
    uint8_t node;            /**< sender node-ID */
    uint8_t data[8];         /**< the 8 EMCY bytes as received */
    uint16_t error_code;     /**< bytes 0..1 */
    uint8_t error_register;  /**< byte 2 (1001h) */
    uint8_t lost;            /**< 1: an EMCY was lost (FIFO full) before this pop */
    uint32_t time_ms;        /**< reception time (master's ms clock) */
} cm_emcy_t;

/** Interrupt callback: irq_mask is the IRQ_STATUS bit (CM_IRQ_STATUS_<NAME>_MASK). */
typedef void (*cm_irq_fn)(cm_ctx_t *ctx, uint32_t irq_mask);
typedef void (*cm_emcy_fn)(cm_ctx_t *ctx, const cm_emcy_t *emcy);

#define CM_IRQ_SOURCES 8u

struct cm_ctx {
    cm_wr_fn wr;           /**< register write (required) */
    cm_rd_fn rd;           /**< register read (required) */
    cm_idle_fn idle;       /**< between two polls (optional) */
    void *user;            /**< for the callbacks (e.g. the peripheral base address) */
    uint32_t max_polls;    /**< bound of every blocking wait, in polls */
    /* filled by cm_identify */
    uint32_t version;      /**< VERSION register */
    uint8_t n_sdo;         /**< SDO channels (SDO_SEL.CHANNELS) */
    uint8_t n_tpdo;        /**< TPDO channels (PDO_INFO) */
    uint8_t n_rpdo;        /**< RPDO channels (PDO_INFO) */
    uint8_t sdo_chan;      /**< SDO_SEL.CHAN last written by the HAL (0xFF: unknown) */
    /* interrupt dispatch (cm_irq_handler), any may be NULL */
    cm_irq_fn on_irq[CM_IRQ_SOURCES]; /**< by IRQ_STATUS bit number */
    cm_emcy_fn on_emcy;    /**< per EMCY popped by the handler (IRQ_STATUS.EMCY) */
};

#define CM_DEFAULT_MAX_POLLS 100000u

/* ---------------------------------------------------------------- set-up, identification */
/** Fill ctx: callbacks, user pointer, max_polls = CM_DEFAULT_MAX_POLLS, nothing else. */
void cm_setup(cm_ctx_t *ctx, cm_wr_fn wr, cm_rd_fn rd, cm_idle_fn idle, void *user);
/** sizeof(cm_ctx_t), for bindings from other languages (a check of their struct layout). */
size_t cm_ctx_size(void);
/** Read ID and VERSION (same major, minor >= the header's), SDO channels and PDO sizes. */
cm_status_t cm_identify(cm_ctx_t *ctx);
/** cm_identify, wait for STATUS.INIT_DONE, then IRQ_ENABLE = irq_enable. */
cm_status_t cm_init(cm_ctx_t *ctx, uint32_t irq_enable);

/* ---------------------------------------------------------------- NMT, SYNC */
#define CM_NMT_START 0x01u
#define CM_NMT_STOP 0x02u
#define CM_NMT_PREOP 0x80u
#define CM_NMT_RESET_NODE 0x81u
#define CM_NMT_RESET_COMM 0x82u
/** Wait for NMT_BUSY = 0, write NMT_CMD (cs, node 0 = all), check REFUSED. */
cm_status_t cm_nmt(cm_ctx_t *ctx, uint8_t cs, uint8_t node);
/** SYNC_PERIOD_US, SYNC_OVERFLOW (0 or 2..240), SYNC_WINDOW_US, then CTRL.SYNC_EN. */
cm_status_t cm_sync_config(cm_ctx_t *ctx, uint32_t period_us, uint8_t overflow,
                           uint32_t window_us, int enable);

/* ---------------------------------------------------------------- SDO */
typedef struct {
    uint32_t size;        /**< bytes transferred (upload: bytes in SDO_BUF) */
    uint32_t abort_code;  /**< CiA 301 abort code when CM_ERR_ABORT, else 0 */
    uint8_t abort_sent;   /**< 1: the master sent the abort (e.g. timeout), 0: the node did */
} cm_sdo_result_t;

/** SDO_TIMEOUT_MS (shared by the channels, taken at each start). */
void cm_sdo_set_timeout(cm_ctx_t *ctx, uint16_t timeout_ms);
/** Polled: start a download of len (1..256) bytes on channel chan; CM_ERR_REFUSED if the
    core refused it (channel busy or owned by the configuration list, node busy on another
    channel, Omni-ID mode). */
cm_status_t cm_sdo_start_download(cm_ctx_t *ctx, uint8_t chan, uint8_t node, uint16_t index,
                                  uint8_t sub, const uint8_t *data, size_t len);
/** Polled: start an upload on channel chan. */
cm_status_t cm_sdo_start_upload(cm_ctx_t *ctx, uint8_t chan, uint8_t node, uint16_t index,
                                uint8_t sub);
/** Polled: one read of SDO_CMD: CM_PENDING, CM_OK (res->size) or CM_ERR_ABORT (res). Only
    after CM_OK from a start on this channel: after CM_ERR_REFUSED nothing runs and DONE still
    belongs to the previous transfer. Never looks at REFUSED. */
cm_status_t cm_sdo_poll(cm_ctx_t *ctx, uint8_t chan, cm_sdo_result_t *res);
/** Copy n bytes (n <= 256) of channel chan's SDO_BUF into buf. */
cm_status_t cm_sdo_read_buf(cm_ctx_t *ctx, uint8_t chan, uint8_t *buf, size_t n);
/** Blocking download (start + poll until DONE, at most max_polls). res may be NULL. */
cm_status_t cm_sdo_download(cm_ctx_t *ctx, uint8_t chan, uint8_t node, uint16_t index,
                            uint8_t sub, const uint8_t *data, size_t len, cm_sdo_result_t *res);
/** Blocking upload into buf (cap bytes); *len = bytes received. CM_ERR_SIZE: more than cap
    (the first cap bytes are copied, res->size holds the full size). res may be NULL. */
cm_status_t cm_sdo_upload(cm_ctx_t *ctx, uint8_t chan, uint8_t node, uint16_t index,
                          uint8_t sub, uint8_t *buf, size_t cap, size_t *len,
                          cm_sdo_result_t *res);

/* ---------------------------------------------------------------- configuration list */
typedef struct {
    uint8_t node;    /**< 1..127 */
    uint16_t index;
    uint8_t sub;
    uint8_t size;    /**< 1..4 bytes */
    uint32_t value;  /**< little-endian bytes as in the SDO frame */
} cm_acfg_entry_t;

typedef struct {
    uint8_t nodes_ok;     /**< nodes whose entries all succeeded */
    uint8_t nodes_fail;   /**< nodes stopped by a failing entry */
} cm_acfg_result_t;

/** Write n entries from entry number first on, plus the node-0 end marker. */
cm_status_t cm_acfg_load(cm_ctx_t *ctx, const cm_acfg_entry_t *entries, size_t n, uint8_t first);
/** ACFG_CTRL.START (and START_NODES); CM_ERR_REFUSED if the core refused it. */
cm_status_t cm_acfg_start(cm_ctx_t *ctx, int start_nodes);
/** Polled: CM_PENDING, CM_OK (no failure) or CM_ERR_CONFIG (res->nodes_fail > 0). */
cm_status_t cm_acfg_poll(cm_ctx_t *ctx, cm_acfg_result_t *res);
/** Blocking: start, then poll until the run finished. */
cm_status_t cm_acfg_run(cm_ctx_t *ctx, int start_nodes, cm_acfg_result_t *res);
/** k-th failure of the last run (0 = first): node, entry number, abort code (0s beyond). */
cm_status_t cm_acfg_failure(cm_ctx_t *ctx, uint8_t k, uint8_t *node, uint8_t *entry,
                            uint32_t *abort_code);

/* ---------------------------------------------------------------- PDO */
typedef struct {
    uint8_t data[8];      /**< bytes beyond dlc are 0 */
    uint8_t dlc;          /**< PDO_CFG.DLC of the channel */
    uint8_t is_new;       /**< NEW before this read (not acknowledged) */
    uint16_t seq;         /**< PDOs stored (wraps): +1 per reception */
    uint8_t sync_count;   /**< SYNC counter byte of the cycle the data belongs to */
    uint16_t len_err;     /**< frames with a wrong DLC (saturates) */
    uint16_t missed;      /**< synchronous cycles without the PDO (saturates) */
} cm_rpdo_t;

#define CM_TPDO_RTR_ALLOWED 0x1u
/** TPDO ch: COB-ID, DLC 0..8, transmission type (241..251 reserved), flags, inhibit time. */
cm_status_t cm_tpdo_config(cm_ctx_t *ctx, uint8_t ch, uint16_t cob_id, uint8_t dlc, uint8_t tt,
                           uint32_t flags, uint16_t inhibit_100us);
/** RPDO ch: COB-ID, expected DLC, producer's transmission type, RTR poll after every SYNC. */
cm_status_t cm_rpdo_config(cm_ctx_t *ctx, uint8_t ch, uint16_t cob_id, uint8_t dlc, uint8_t tt,
                           int rtr_poll);
/** Set channel ch's staging register to data[0..len-1] (rest 0) and COMMIT it (commit != 0;
    sent from the next SYNC on for TT 0..252, at once for 253..255); trigger != 0 also
    requests a transmission (TT 254/255 now, TT 0 after the next SYNC). */
cm_status_t cm_tpdo_set(cm_ctx_t *ctx, uint8_t ch, const uint8_t *data, size_t len, int commit,
                        int trigger);
/** 1 while a commit of TPDO ch waits for the next SYNC (PDO_TX_PENDING bit ch). */
int cm_tpdo_pending(cm_ctx_t *ctx, uint8_t ch);
/** Snapshot of RPDO ch (one consistent reception); ack != 0 clears its NEW flag. */
cm_status_t cm_rpdo_get(cm_ctx_t *ctx, uint8_t ch, int ack, cm_rpdo_t *out);
/** NEW flags of all RPDO channels (bit k = channel k). */
uint32_t cm_rpdo_new(cm_ctx_t *ctx);

/* ---------------------------------------------------------------- node supervision */
#define CM_NODE_MODE_OFF 0u
#define CM_NODE_MODE_HEARTBEAT 1u
#define CM_NODE_MODE_GUARDING 2u
#define CM_NODE_AUTOSTART 0x1u
#define CM_NODE_RESET_ON_LOSS 0x2u

typedef struct {
    uint8_t nmt_state;    /**< 00h boot-up, 04h stopped, 05h operational, 7Fh pre-operational */
    uint8_t alive;
    uint8_t lost;         /**< sticky */
    uint8_t toggle_err;   /**< sticky */
    uint8_t bootup;       /**< sticky */
    uint32_t last_ms;     /**< time of the node's last message */
} cm_node_status_t;

/** Supervision slot: node-ID, mode, heartbeat consumer / guard time, life factor, flags. */
cm_status_t cm_node_config(cm_ctx_t *ctx, uint8_t slot, uint8_t node_id, uint8_t mode,
                           uint16_t time_ms, uint8_t life_factor, uint32_t flags);
cm_status_t cm_node_status(cm_ctx_t *ctx, uint8_t slot, cm_node_status_t *out);
/** Clear the sticky LOST / TOGGLE_ERR / BOOTUP flags of a slot. */
cm_status_t cm_node_clear(cm_ctx_t *ctx, uint8_t slot);

/* ---------------------------------------------------------------- EMCY, interrupts */
/** Read and drop the EMCY FIFO head; CM_ERR_EMPTY when there is none. */
cm_status_t cm_emcy_pop(cm_ctx_t *ctx, cm_emcy_t *out);
/** IRQ_ENABLE = mask (CM_IRQ_STATUS_<NAME>_MASK bits). */
void cm_irq_enable(cm_ctx_t *ctx, uint32_t mask);
/** Interrupt service: pending = IRQ_STATUS & IRQ_ENABLE, cleared (W1C) before the dispatch
    (an event during the dispatch raises the interrupt again); with on_emcy set, the EMCY
    FIFO is popped until empty (at most 128 messages) and on_emcy called for each; then
    on_irq[bit] for each pending bit. Returns the pending bits. */
uint32_t cm_irq_handler(cm_ctx_t *ctx);

#ifdef __cplusplus
}
#endif

#endif /* CANOPEN_MASTER_H */
