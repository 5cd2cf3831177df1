/*
    nanovdb_drjit/kernel_replay.h -- a C++ pass of kernels recorded once on
    the backend and replayed with new inputs: Dr.Jit's kernel freezing (the
    jit_freeze_* calls under dr.freeze), for C++ code

    Beyond PNanoVDB. A pass of many small kernels pays, every call, for
    tracing its operations, generating their code and looking it up in the
    cache, on the host, while the backend waits. The majorant rebuild
    (majorant_rebuild.h) is such a pass: about 45 kernels, 7,000 traced
    operations. A replay launches the recorded kernels on the new inputs
    with none of that.

    The pass may read only its `inputs` (JIT variables, evaluated) and what
    it creates itself; every number that is not an input is a constant of
    the recording, so a call whose constants differ (`key`) records again.
    A pass that reads another variable fails to record (Dr.Jit raises): it
    then runs traced, that call and every later one, with a warning.
    Traced too: inside another recording (dr.freeze), and when kernel
    freezing is off (JitFlag::KernelFreezing).
*/

#pragma once

#include <drjit-core/jit.h>

#include <cstdint>
#include <exception>
#include <memory>
#include <vector>

namespace nanovdb_drjit {

class KernelReplay {
public:
    /// Calls recorded (the first, and those whose key changed) and replayed
    uint32_t recordings() const { return m_recordings; }
    uint32_t replays() const { return m_replays; }
    /// Whether the last call replayed
    bool replayed() const { return m_replayed; }
    /// Whether passes run traced from now on (a recording or replay failed)
    bool off() const { return m_off; }

    /**
     * `pass()` returns its outputs as JIT indices, each an owned reference,
     * evaluated. `key`: the pass's constants (a call with other ones records
     * again). Returns the outputs (owned references) of the pass or of its
     * replay.
     */
    template <typename Pass>
    std::vector<uint32_t> run(JitBackend backend, const std::vector<uint32_t> &inputs,
                              const std::vector<uint64_t> &key, Pass &&pass) {
        m_replayed = false;
        if (m_off || !jit_flag(JitFlag::KernelFreezing) || jit_flag(JitFlag::FreezingScope))
            return pass();
        std::vector<uint32_t> in;
        in.reserve(inputs.size());
        for (uint32_t i : inputs) { // (each once; none of 0, an empty array)
            bool seen = i == 0;
            for (uint32_t j : in)
                seen |= j == i;
            if (!seen) {
                jit_var_schedule(i);
                in.push_back(i);
            }
        }
        jit_eval();
        if (m_recording && key == m_key) {
            try {
                if (jit_freeze_dry_run(m_recording.get(), in.data())) {
                    std::vector<uint32_t> out(m_outputs);
                    jit_freeze_replay(m_recording.get(), in.data(), out.data());
                    ++m_replays;
                    m_replayed = true;
                    return out;
                }
            } catch (const std::exception &e) {
                return give_up("replay", e, {}, pass);
            }
        }
        m_recording.reset();
        jit_freeze_start(backend, in.data(), uint32_t(in.size()));
        std::vector<uint32_t> out;
        try {
            out = pass();
            jit_freeze_pause(backend);
            m_recording.reset(jit_freeze_stop(backend, out.data(), uint32_t(out.size())), Destroy());
        } catch (const std::exception &e) {
            jit_freeze_abort(backend);
            return give_up("recording", e, out, pass);
        }
        m_key = key;
        m_outputs = out.size();
        ++m_recordings;
        return out;
    }

private:
    /// A recording or replay that failed: the pass traced, now and after
    template <typename Pass>
    std::vector<uint32_t> give_up(const char *what, const std::exception &e,
                                  const std::vector<uint32_t> &partial, Pass &&pass) {
        for (uint32_t i : partial)
            jit_var_dec_ref(i);
        m_recording.reset();
        m_off = true;
        jit_log(LogLevel::Warn, "KernelReplay: the %s failed (%s); the pass runs traced from now on",
                what, e.what());
        return pass();
    }

    struct Destroy {
        void operator()(Recording *r) const { jit_freeze_destroy(r); }
    };
    std::shared_ptr<Recording> m_recording; ///< (shared: copies replay the same)
    std::vector<uint64_t> m_key;
    size_t m_outputs = 0;
    uint32_t m_recordings = 0, m_replays = 0;
    bool m_off = false, m_replayed = false;

public:
    KernelReplay() : m_recording(nullptr, Destroy()) {}
};

} // namespace nanovdb_drjit
