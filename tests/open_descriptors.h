// The open file descriptors of this process, for the leak checks of the bad-file test and the fuzz
// targets.
#pragma once

#include <dirent.h>

namespace evkit::test {

// Entries of /proc/self/fd, less the listing's own descriptor; -1 when it cannot be read.
inline int openDescriptors() {
  DIR* dir = ::opendir("/proc/self/fd");
  if (!dir) return -1;
  int count = 0;
  while (const dirent* entry = ::readdir(dir)) count += entry->d_name[0] != '.';
  ::closedir(dir);
  return count - 1;
}

}  // namespace evkit::test
