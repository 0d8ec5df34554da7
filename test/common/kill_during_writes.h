// Kills a process in the middle of saving a file, at many moments of the
// write, as a crash or a SIGKILL of the node during an autosave would.
#ifndef ROTATION_AVERAGING_TEST_COMMON_KILL_DURING_WRITES_H_
#define ROTATION_AVERAGING_TEST_COMMON_KILL_DURING_WRITES_H_

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <functional>
#include <thread>

namespace rotation_averaging {

// `save` writes the file once and returns whether it succeeded. Each round
// forks a child that saves over and over until it is killed with SIGKILL,
// after a delay that moves through the first two saves from round to round
// (the duration of one save is measured in this process first), then calls
// `check`, which tests what the killed saves left. Returns the number of
// rounds whose child was killed while it was still saving.
inline int KillDuringWrites(const std::function<bool()>& save, const std::function<void(int round)>& check,
                            int rounds) {
  const auto start = std::chrono::steady_clock::now();
  EXPECT_TRUE(save());
  const double save_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  int killed = 0;
  for (int round = 0; round < rounds; ++round) {
    const pid_t child = ::fork();
    if (child == 0) {
      // Only async-signal-safe exits from here: no gtest, no destructors.
      for (;;) {
        if (!save()) ::_exit(3);
      }
    }
    EXPECT_GT(child, 0);
    if (child <= 0) return killed;
    const double delay_s = 2.0 * save_s * (round + 0.5) / rounds;
    std::this_thread::sleep_for(std::chrono::duration<double>(delay_s));
    ::kill(child, SIGKILL);
    int status = 0;
    ::waitpid(child, &status, 0);
    if (WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) ++killed;
    EXPECT_FALSE(WIFEXITED(status)) << "round " << round << ": the saving child exited with status "
                                    << WEXITSTATUS(status) << " before it was killed";
    check(round);
  }
  return killed;
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_TEST_COMMON_KILL_DURING_WRITES_H_
