// Pin-level driver of a Verilated board top level (lodestar.hdl.boards.GatewareTop written as
// module "top", Verilated with --prefix Vtop), built as a shared library for ctypes
// (lodestar/fly/verilated.py): no Python runs per clock.
//
// Two free-running clocks, event-driven in picoseconds: `clk` (sync) and `pix_clk` (the
// sensor's PIXCLK), each toggled at its half period with one eval per edge (both in one eval
// when they coincide: equal periods and no offset).  The sensor bus (pix_d, line_valid, frame_valid) changes right after a
// PIXCLK falling edge, as the MT9P031 launches it, and is sampled by the next rising edge.
// The SPI master drives SCK, MOSI and CS_N (mode 0: MOSI set half an SCK period before the
// rising edge, MISO sampled just before it), between the pixel activity (a frame is played
// whole, then transactions run while the sensor bus idles).  Every function returns after
// a whole number of picoseconds; time only moves forward.  Time is compressed where the
// gateware idles (short blanking, transactions between frames), so before each frame the
// board's free-running microsecond counter (`timestamp`, with its prescaler `pre`; public
// through top.vlt) is set to the frame's instant on the twin's clock: the header timestamps
// the gateware latches are then the ones the board would latch.
#include <cstdint>

#include "Vtop.h"
#include "Vtop___024root.h"
#include "verilated.h"

struct Twin {
    VerilatedContext context;
    Vtop* top;
    uint64_t now;          // ps
    uint64_t next_sync;    // next edge of clk, ps
    uint64_t next_pix;     // next edge of pix_clk, ps
    uint32_t sync_half;
    uint32_t pix_half;
};

// Run every clock edge up to and including time `until` (ps).
static void run_until(Twin* t, uint64_t until) {
    Vtop* top = t->top;
    while (true) {
        uint64_t next = t->next_sync < t->next_pix ? t->next_sync : t->next_pix;
        if (next > until) break;
        if (t->next_sync == next) {
            top->clk = !top->clk;
            t->next_sync += t->sync_half;
        }
        if (t->next_pix == next) {
            top->pix_clk = !top->pix_clk;
            t->next_pix += t->pix_half;
        }
        top->eval();
    }
    t->now = until;
}

// Advance to just after the next falling edge of pix_clk.
static void to_pix_fall(Twin* t) {
    // pix_clk is high iff its next edge falls; run to that falling edge
    if (!t->top->pix_clk) run_until(t, t->next_pix);      // the rising edge first
    run_until(t, t->next_pix);
}

extern "C" {

// `pix_offset_ps`: when PIXCLK's edges come after clk's (0 with equal periods: the two
// clocks change in the same eval, half the evals of two free-running clocks).
Twin* twin_new(uint32_t sync_period_ps, uint32_t pix_period_ps, uint32_t pix_offset_ps) {
    Twin* t = new Twin;
    t->top = new Vtop{&t->context};
    t->now = 0;
    t->sync_half = sync_period_ps / 2;
    t->pix_half = pix_period_ps / 2;
    t->next_sync = t->sync_half;
    t->next_pix = t->pix_half + pix_offset_ps;
    Vtop* top = t->top;
    top->clk = 0;
    top->pix_clk = 0;
    top->rst = 1;
    top->pix_rst = 1;
    top->cs_n = 1;
    top->sck = 0;
    top->mosi = 0;
    top->pll_losses = 0;
    top->clock_ok = 1;           // the board's qualified PLL lock
    top->sensor_in_reset = 0;
    top->pix_d = 0;
    top->line_valid = 0;
    top->frame_valid = 0;
    top->eval();
    run_until(t, 8ull * sync_period_ps + 8ull * pix_period_ps);
    top->rst = 0;
    top->pix_rst = 0;
    run_until(t, t->now + 4ull * sync_period_ps);
    return t;
}

void twin_free(Twin* t) {
    t->top->final();
    delete t->top;
    delete t;
}

int twin_irq(Twin* t) { return t->top->irq; }

void twin_pll_losses(Twin* t, uint32_t gray) { t->top->pll_losses = gray; }

// Set the microsecond counter to `us` at the start of a count (prescaler 0).
void twin_set_time(Twin* t, uint32_t us) {
    t->top->rootp->top__DOT__timestamp = us;
    t->top->rootp->top__DOT__pre = 0;
}

// Play one frame: `rows` rows of `width` pixels from `pixels` (row-major uint16), each
// followed by `hblank` PIXCLKs with LINE_VALID low, FRAME_VALID high from the first pixel to
// the last; then `vblank` PIXCLKs with both low.  `rows` may be fewer than the frame's
// height: the frame ends early (FRAME_VALID falls), as a truncated frame does.
void twin_frame(Twin* t, const uint16_t* pixels, uint32_t width, uint32_t rows,
                uint32_t hblank, uint32_t vblank) {
    Vtop* top = t->top;
    for (uint32_t y = 0; y < rows; y++) {
        const uint16_t* row = pixels + (uint64_t)y * width;
        for (uint32_t x = 0; x < width; x++) {
            to_pix_fall(t);
            top->frame_valid = 1;
            top->line_valid = 1;
            top->pix_d = row[x];
        }
        for (uint32_t k = 0; k < hblank; k++) {
            to_pix_fall(t);
            top->line_valid = 0;
            top->frame_valid = (y + 1 < rows) ? 1 : 0;
        }
    }
    for (uint32_t k = 0; k < vblank; k++) {
        to_pix_fall(t);
        top->line_valid = 0;
        top->frame_valid = 0;
    }
}

// Chip select: low (`level` 0) then `setup_ps` before the first SCK edge, or high after
// `hold_ps`, then `gap_ps` high.
void twin_cs(Twin* t, int level, uint32_t setup_ps, uint32_t hold_ps, uint32_t gap_ps) {
    if (level == 0) {
        t->top->cs_n = 0;
        run_until(t, t->now + setup_ps);
    } else {
        run_until(t, t->now + hold_ps);
        t->top->cs_n = 1;
        run_until(t, t->now + gap_ps);
    }
}

// Clock `n` bytes out on MOSI (MSB first) and the bytes on MISO into `miso`, SCK high and
// low `half_ps` each.
void twin_xfer(Twin* t, const uint8_t* mosi, uint8_t* miso, uint32_t n, uint32_t half_ps) {
    Vtop* top = t->top;
    for (uint32_t i = 0; i < n; i++) {
        uint8_t got = 0;
        for (int bit = 7; bit >= 0; bit--) {
            top->mosi = (mosi[i] >> bit) & 1;
            run_until(t, t->now + half_ps);
            got |= (uint8_t)((top->miso & 1) << bit);
            top->sck = 1;
            run_until(t, t->now + half_ps);
            top->sck = 0;
        }
        miso[i] = got;
    }
}

}  // extern "C"
