/*
    nanovdb_mitsuba/frozen.h -- what our plugins need for Dr.Jit's frozen
    functions (dr.freeze)

    A frozen function records its kernels once and replays them: a replay
    runs none of our C++, and Dr.Jit reads the plugins' variables as the
    function's inputs by traversing them (traverse_1_cb_ro), before every
    recording and replay. So:
     - recording_frozen_function(): inside a recording, nothing may read a
       variable back to the host (Dr.Jit refuses it);
     - NVDB_MI_TRAVERSE_CB_REFRESHED(Base, refresh, members...): Mitsuba's
       MI_TRAVERSE_CB, with `refresh` run first in the read traversal: what
       a plugin derives from its parameters lazily (a volume's majorants, a
       medium's emission table) is brought up to date there, outside the
       recording, so that a replay reads the current arrays.
*/

#pragma once

#include <mitsuba/core/fwd.h>
#include <drjit/jit.h>

NAMESPACE_BEGIN(mitsuba)

/// Inside the recording of a frozen function (dr.freeze): no reads
template <typename Float> bool recording_frozen_function() {
    if constexpr (drjit::is_jit_v<Float>)
        return jit_flag(JitFlag::FreezingScope);
    else
        return false;
}

NAMESPACE_END(mitsuba)

#define NVDB_MI_TRAVERSE_CB_REFRESHED(Base, refresh, ...)                                  \
    void traverse_1_cb_ro(void *payload, drjit::detail::traverse_callback_ro fn)           \
        const override {                                                                   \
        if (!jit_flag(JitFlag::EnableObjectTraversal))                                     \
            return;                                                                        \
        refresh;                                                                           \
        Base::traverse_1_cb_ro(payload, fn);                                               \
        DRJIT_MAP(DR_TRAVERSE_MEMBER_RO, __VA_ARGS__)                                      \
    }                                                                                      \
    MI_TRAVERSE_CB_RW(Base, __VA_ARGS__)
