// Co-simulation harness of the lodestar detector (Verilator).
//
// Plays a stimulus file into the detector one word per clock, so that no Python runs per
// pixel, and writes every record and trailer the detector emits to an output file.  The
// files are named by the plusargs +stim=PATH and +out=PATH; playback starts on the first
// rising clock edge with `start` high and `done` rises after the last word.  Two builds
// (lodestar/cosim/runner.py): under cocotb the harness clocks itself; with COSIM_NATIVE
// defined, native.cpp clocks it.
//
// A clock's word (64 bits), fields LSB first: data[15:0], eol[16], sof[17], valid[18],
// records ready[19], register write enable[20], reset[21], register address[27:24],
// register data[63:32].  The file (binary, big-endian) holds commands of 64 bits:
//   * bit 23 (RUN) set: the next N = word[63:32] clocks are pixels, N 16-bit words follow
//     in the file; each clock is this command's word with data = the pixel, sof only on
//     the first and eol only on the last (when set here).  N <= RUN_MAX.
//   * bit 22 (REPEAT) set: this word with data[63:32] = 0 for N = word[63:32] clocks.
//   Bits 22 and 23 of a clock's word are always 0.
//   * else: this word for one clock.
// lodestar/cosim/runner.py (Stimulus.save) writes it; reading a row per file call, not a
// word per clock, is what makes the playback fast.  Output: "R <hex>" per record and
// "T <hex>" per trailer, the packed payloads of hdl/layouts.py, in the order they leave the
// detector, and "X 0" for every clock of a reset (records of the interrupted frame have
// no trailer).
module cosim_harness #(
    parameter PB = 12,
    parameter REC_W = 345,
    parameter TR_W = 256,
    parameter ADDR_W = 4,
    parameter RUN_MAX = 4096
) (
`ifdef COSIM_NATIVE
    input clk,
`endif
    input start /*verilator public_flat_rw*/,
    output reg done /*verilator public_flat_rw*/
);
`ifndef COSIM_NATIVE
    // Under cocotb the clock runs inside the simulation (Verilator --timing): no Python per
    // clock, and STEP_CLOCKS clocks per 10 ns time step, because cocotb's main loop runs the
    // VPI bookkeeping of Verilator on every time step (about 30 % of the playback at two
    // steps per clock).  A rising edge is followed, once the flip-flops have taken their
    // values (`phase` changes in the NBA region), by the falling edge, then by the next
    // rising edge after a zero delay (the inactive region, when all combinational logic has
    // settled).  Built with COSIM_NATIVE (runner.py's native build), `clk` is a port that
    // native.cpp toggles: no timing coroutines, no VPI (docs/cosim.md).
    localparam STEP_CLOCKS = 1000;
    reg clk = 0;
    reg phase = 0;
    always @(posedge clk) phase <= ~phase;
    initial begin
        forever begin
            repeat (STEP_CLOCKS) begin
                clk = 1;
                @(phase);
                clk = 0;
                #0;
            end
            #10;
        end
    end
`endif

    reg [63:0] word;
    reg running;
    integer fd_in;
    integer fd_out;
    integer got;
    reg [63:0] cmd;              // the command being played
    reg [31:0] left;             // its clocks still to play
    reg [31:0] index;            // clock of a run
    reg [15:0] run [0:RUN_MAX-1];
    string stim_path;
    string out_path;

    wire [REC_W-1:0] rec_payload;
    wire rec_valid;
    wire [TR_W-1:0] tr_payload;
    wire tr_valid;
    wire rst = word[21] | ~running;

    detector dut (
        .clk(clk),
        .rst(rst),
        .pixels__valid(word[18]),
        .pixels__payload({word[16], word[17], word[PB-1:0]}),
        .records__ready(word[19]),
        .records__valid(rec_valid),
        .records__payload(rec_payload),
        .trailer__ready(1'b1),
        .trailer__valid(tr_valid),
        .trailer__payload(tr_payload),
        .reg_addr(word[24 +: ADDR_W]),
        .reg_data(word[63:32]),
        .reg_en(word[20]),
        .reg_error(),
        .busy(),
        .frame_counter(),
        .timestamp(32'd0),
        .trailer_lost(),
        .fault()
    );

    initial begin
        done = 0;
        running = 0;
        left = 0;
        word = 64'h0000_0000_0020_0000;
    end

    always @(posedge clk) begin
        if (!running && !done && start) begin
            if (!$value$plusargs("stim=%s", stim_path)) $fatal(1, "cosim_harness: +stim= missing");
            if (!$value$plusargs("out=%s", out_path)) $fatal(1, "cosim_harness: +out= missing");
            fd_in = $fopen(stim_path, "rb");
            fd_out = $fopen(out_path, "w");
            if (fd_in == 0) $fatal(1, "cosim_harness: cannot open the stimulus");
            if (fd_out == 0) $fatal(1, "cosim_harness: cannot open the output");
            running <= 1;
        end
        if (running) begin
            if (word[21]) $fwrite(fd_out, "X 0\n");
            if (rec_valid && word[19]) $fwrite(fd_out, "R %h\n", rec_payload);
            if (tr_valid) $fwrite(fd_out, "T %h\n", tr_payload);
            if (left == 0) begin
                got = $fread(cmd, fd_in);
                left = cmd[63:32];
                index = 0;
                if (got != 8) begin
                    left = 0;
                end else if (cmd[23]) begin
                    if (left > RUN_MAX) $fatal(1, "cosim_harness: run longer than RUN_MAX");
                    got = $fread(run, fd_in, 0, left);
                    if (got != 2 * left) $fatal(1, "cosim_harness: stimulus ends in a run");
                end else if (!cmd[22]) begin
                    left = 1;
                end
            end
            if (left == 0) begin
                $fclose(fd_in);
                $fclose(fd_out);
                running <= 0;
                done <= 1;
            end else if (cmd[23]) begin
                word <= {32'b0, cmd[31:24], 2'b0, cmd[21:18], cmd[17] && index == 0,
                         cmd[16] && left == 1, run[index]};
                index = index + 1;
                left = left - 1;
            end else if (cmd[22]) begin
                word <= {32'b0, cmd[31:24], 2'b0, cmd[21:0]};
                left = left - 1;
            end else begin
                word <= cmd;
                left = 0;
            end
        end
    end
endmodule
