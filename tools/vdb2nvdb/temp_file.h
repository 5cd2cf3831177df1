// Output files written under a temporary name and renamed into place only
// when complete, so that an error or a signal leaves no partial output.
#pragma once

#include <string>

namespace vdb2nvdb {

/// Writes `path` through a temporary file in the same directory that is
/// renamed into place by commit(); removed if never committed (also on
/// SIGINT/SIGTERM).
class TempFile {
public:
    explicit TempFile(const std::string &path);
    ~TempFile();
    TempFile(const TempFile &) = delete;
    TempFile &operator=(const TempFile &) = delete;
    const std::string &tmp_path() const { return m_tmp; }
    const std::string &path() const { return m_path; }
    void commit();
    void discard();
private:
    std::string m_path, m_tmp;
    bool m_done = false;
    int m_slot = -1;
};

/// Installs SIGINT/SIGTERM handlers that remove live temporary files.
void install_signal_handlers();

} // namespace vdb2nvdb
